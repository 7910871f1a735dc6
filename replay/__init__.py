"""rimu.replay: flights (simulated or recorded), fault injection, CAN replay and reports."""

from replay.faults import FAULT_KINDS, Fault, parse_fault
from replay.flight import (
    Flight,
    iter_flight,
    load_flight_dir,
    save_flight_dir,
    simulate_flight,
)
from replay.report import REPORT_SCHEMA, build_report, format_report

__all__ = [
    "FAULT_KINDS",
    "REPORT_SCHEMA",
    "Fault",
    "Flight",
    "build_report",
    "format_report",
    "iter_flight",
    "load_flight_dir",
    "parse_fault",
    "save_flight_dir",
    "simulate_flight",
]
