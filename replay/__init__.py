"""rimu.replay: flights (simulated or recorded), fault injection, CAN replay and reports."""

from fdi.lazy import attach

_EXPORTS = {
    "AuxChannels": "replay.flight_data",
    "ChannelMap": "replay.channel_map",
    "FAULT_KINDS": "replay.faults",
    "Fault": "replay.faults",
    "Flight": "replay.flight_data",
    "FrameAccounting": "replay.accounting",
    "REPORT_SCHEMA": "replay.report",
    "StreamDecoder": "replay.live",
    "apply_faults": "replay.scenario",
    "build_report": "replay.report",
    "default_channel_map": "replay.channel_map",
    "format_report": "replay.report",
    "inject": "replay.scenario",
    "iter_flight": "replay.flight_sim",
    "load_channel_map": "replay.channel_map",
    "load_flight_dir": "replay.flight_io",
    "load_scenario": "replay.scenario",
    "parse_fault": "replay.faults",
    "read_frames": "replay.logio",
    "read_log": "replay.logio",
    "run_live": "replay.live",
    "save_flight_dir": "replay.flight_io",
    "simulate_flight": "replay.flight_sim",
    "write_flight_log": "replay.logio",
}
"""Public name → module defining it (imported on first use, PEP 562)."""
__all__ = [
    "FAULT_KINDS",
    "REPORT_SCHEMA",
    "AuxChannels",
    "ChannelMap",
    "Fault",
    "Flight",
    "FrameAccounting",
    "StreamDecoder",
    "apply_faults",
    "build_report",
    "default_channel_map",
    "format_report",
    "inject",
    "iter_flight",
    "load_channel_map",
    "load_flight_dir",
    "load_scenario",
    "parse_fault",
    "read_frames",
    "read_log",
    "run_live",
    "save_flight_dir",
    "simulate_flight",
    "write_flight_log",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
