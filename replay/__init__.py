"""rimu.replay: flights (simulated or recorded), fault injection, CAN replay and reports."""

from replay.accounting import FrameAccounting
from replay.chain import MonitorChain, chain_for_flight, chain_for_map
from replay.channel_map import ChannelMap, default_channel_map, load_channel_map
from replay.envelope import flight_envelope
from replay.faults import FAULT_KINDS, Fault, parse_fault
from replay.flight_data import AuxChannels, Flight
from replay.flight_io import load_flight_dir, save_flight_dir
from replay.flight_sim import iter_flight, simulate_flight
from replay.live import StreamDecoder, run_live
from replay.log_events import LogEvent
from replay.logio import read_frames, read_log, write_flight_log
from replay.report import REPORT_SCHEMA, build_report, format_report
from replay.scenario import apply_faults, inject, load_scenario
from replay.time_offsets import StreamAligner, apply_time_offsets

__all__ = [
    "FAULT_KINDS",
    "REPORT_SCHEMA",
    "AuxChannels",
    "ChannelMap",
    "Fault",
    "Flight",
    "FrameAccounting",
    "LogEvent",
    "MonitorChain",
    "StreamAligner",
    "StreamDecoder",
    "apply_faults",
    "apply_time_offsets",
    "build_report",
    "chain_for_flight",
    "chain_for_map",
    "default_channel_map",
    "flight_envelope",
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
