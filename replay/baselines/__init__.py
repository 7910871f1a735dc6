"""The autopilots' own rules for a bad IMU, as named baselines beside rimu's answer.

- :mod:`replay.baselines.px4`: PX4's EKF2 IMU selector (inconsistency to the mean of the
  IMUs, low-passed, accumulated above 7 °/s, fault at 15°) and its sensor validator
  (stale, timeout);
- :mod:`replay.baselines.ardupilot`: ArduPilot's IMU consistency checks (each IMU against
  the primary, 5 °/s / 0.75 m/s², consistent for the last 10 s);
- :mod:`replay.baselines.common`: the IMU triads they read and the answer they give;
- :mod:`replay.baselines.compare`: running them on a flight and the report's
  ``"baselines"`` block beside rimu's answer; :mod:`replay.baselines.plot` the plot.

The rules are described from the autopilots' code in ``docs/baselines.md``; each module
says what of the autopilot's logic it leaves out and why.
"""

from replay.baselines.ardupilot import (
    ArduPilotConsistency,
    ArduPilotSettings,
    ardupilot_consistency,
)
from replay.baselines.common import (
    BASELINE_SCHEMA,
    BaselineEvent,
    BaselineResult,
    Triads,
    triads_from_flight,
)
from replay.baselines.compare import (
    BASELINES,
    BASELINES_SCHEMA,
    baselines_record,
    fault_outcome,
    format_baselines,
    parse_baselines,
    run_baselines,
)
from replay.baselines.px4 import PX4Selector, PX4Settings, px4_selector

__all__ = [
    "BASELINES",
    "BASELINES_SCHEMA",
    "BASELINE_SCHEMA",
    "ArduPilotConsistency",
    "ArduPilotSettings",
    "BaselineEvent",
    "BaselineResult",
    "PX4Selector",
    "PX4Settings",
    "Triads",
    "ardupilot_consistency",
    "baselines_record",
    "fault_outcome",
    "format_baselines",
    "parse_baselines",
    "px4_selector",
    "run_baselines",
    "triads_from_flight",
]
