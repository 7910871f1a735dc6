"""ArduPilot's rule for a bad IMU, run on a log's samples: the IMU consistency checks.

What ArduPilot does (``/work/shared/AUTOPILOTS.md``, read from ArduPilot's
``libraries/AP_Arming/AP_Arming.cpp`` and ``libraries/AP_InertialSensor``), in the terms
used here, per sample and IMU ``i`` ≥ 2 (IMU 1 is the primary):

- gyros: inconsistent when ``|g_i − g_1| > 5 °/s``;
- accelerometers: ``d = a_i − a_1`` with its z component halved (``d_z ← d_z / 2``),
  inconsistent when ``|d| > 0.75 m/s²`` (``ARMING_ACCTHRESH``), the threshold tripled for
  the third IMU and beyond;
- the set passes only when every IMU has been consistent for the last 10 s: the rule
  flags at the first inconsistent sample and clears 10 s after the last one.

The check compares each IMU with the primary and names the IMU whose comparison failed;
it never names the primary itself (a faulty primary makes every other IMU inconsistent,
and the first of them is named). With two IMUs it cannot know which of the two is wrong:
it flags and blames nobody here. With three or more the IMU blamed is the first (lowest
numbered) inconsistent one at the latest inconsistent sample.

Left out (:data:`LEFT_OUT`): EKF3 lane switching. Its per-core error scores are the cores'
innovation test ratios against GPS, barometer, magnetometer and airspeed; the IMU samples
carry none of them, and a stand-in made from the IMU samples would be a rule of ours, not
ArduPilot's. Also the 10 s wait after boot before the first pass (a log starts anywhere
in a session: the check starts as passed).

:class:`ArduPilotConsistency` runs the rule sample by sample (:meth:`~ArduPilotConsistency.step`)
or over a block (:meth:`~ArduPilotConsistency.run`), both through :func:`_ap_kernel`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from fdi.errors import ConfigError
from fdi.units import DPS
from replay.baselines.common import (
    BaselineEvent,
    BaselineResult,
    StreamingRule,
    Triads,
    answer_events,
)

__all__ = ["ACCEL_THIRD_IMU_FACTOR", "ACCEL_Z_FACTOR", "ARMING_ACCTHRESH_MPS2",
           "CONSISTENT_FOR_S", "GYRO_CONSISTENCY_DPS", "LEFT_OUT", "ArduPilotAnswer",
           "ArduPilotConsistency", "ArduPilotSettings", "ardupilot_consistency"]

GYRO_CONSISTENCY_DPS = 5.0
"""Gyro consistency threshold against the primary (°/s)."""
ARMING_ACCTHRESH_MPS2 = 0.75
"""``ARMING_ACCTHRESH``: accelerometer consistency threshold against the primary (m/s²)."""
ACCEL_THIRD_IMU_FACTOR = 3.0
"""The accelerometer threshold is multiplied by this for the third IMU and beyond."""
ACCEL_Z_FACTOR = 0.5
"""The z component of an accelerometer difference is multiplied by this."""
CONSISTENT_FOR_S = 10.0
"""All IMUs must have been consistent for this long (s)."""

LEFT_OUT = (
    "EKF3 lane switching: its error scores are the cores' innovation test ratios against "
    "GPS, barometer, magnetometer and airspeed, which IMU samples do not carry",
    "the 10 s wait after boot before the first pass: a log starts anywhere in a session",
    "switching of the primary IMU: the primary stays IMU 1",
)
"""What of ArduPilot's logic :class:`ArduPilotConsistency` does not run, and why."""

REASONS = ("none", "inconsistent with the primary (three or more IMUs)",
           "inconsistent with the primary: two IMUs, not isolated")


@dataclass(frozen=True)
class ArduPilotSettings:
    """The rule's parameters (SI).

    Attributes
    ----------
    threshold : float
        Consistency threshold (rad/s for gyros, m/s² for accelerometers).
    third_imu_factor : float
        Threshold factor for the third IMU and beyond (accelerometers: 3; gyros: 1).
    z_factor : float
        Factor on the z component of the difference (accelerometers: 0.5; gyros: 1).
    consistent_for_s : float
        How long every IMU must have been consistent (s).
    """

    threshold: float
    third_imu_factor: float = 1.0
    z_factor: float = 1.0
    consistent_for_s: float = CONSISTENT_FOR_S

    @classmethod
    def defaults(cls, kind: str = "gyro") -> ArduPilotSettings:
        """ArduPilot's defaults for a gyro or accelerometer set (converted to SI here)."""
        if kind == "gyro":
            return cls(GYRO_CONSISTENCY_DPS * DPS)
        if kind == "accel":
            return cls(ARMING_ACCTHRESH_MPS2, ACCEL_THIRD_IMU_FACTOR, ACCEL_Z_FACTOR)
        raise ConfigError(f"ArduPilot baseline: unknown sensor kind {kind!r} (gyro or accel)")

    def autopilot_units(self, kind: str) -> dict[str, Any]:
        """The parameters as ArduPilot states them, in its units."""
        if kind == "gyro":
            out: dict[str, Any] = {"gyro_consistency_deg_s": self.threshold / DPS}
        else:
            out = {"ARMING_ACCTHRESH_m_s2": self.threshold,
                   "third_imu_factor": self.third_imu_factor, "z_factor": self.z_factor}
        out["consistent_for_s"] = self.consistent_for_s
        out["primary"] = "IMU 1"
        return out


@njit(cache=True)
def _ap_kernel(t, x, ok, p, state, o_flag, o_blame, o_why, o_diff, o_val
               ):  # pragma: no cover - compiled
    """The check over a block; ``p`` = [threshold, third-IMU factor, z factor, window s],
    ``state`` = [time of the last inconsistent sample (−inf: none), IMU named then].
    Outputs per row: flagged, blamed, why (REASONS index), the difference of each IMU to the
    primary divided by its threshold (k,; NaN where not compared), the value reported."""
    N, k = ok.shape
    thr, third, zf, window = p[0], p[1], p[2], p[3]
    for r in range(N):
        first = -1
        worst = 0.0
        for i in range(k):
            o_diff[r, i] = np.nan
        if ok[r, 0]:
            o_diff[r, 0] = 0.0
            for i in range(1, k):
                if not ok[r, i]:
                    continue
                s2 = 0.0
                for a in range(3):
                    d = x[r, i, a] - x[r, 0, a]
                    if a == 2:
                        d *= zf
                    s2 += d * d
                lim = thr * (third if i >= 2 else 1.0)
                q = np.sqrt(s2) / lim
                o_diff[r, i] = q
                if q > 1.0 and first < 0:
                    first = i
                if q > worst:
                    worst = q
        if first >= 0:
            state[0] = t[r]
            state[1] = first
        flagged = state[0] > -np.inf and t[r] - state[0] < window
        o_flag[r] = flagged
        if flagged:
            b = int(state[1])
            o_blame[r] = b if k >= 3 else -1
            o_why[r] = 1 if k >= 3 else 2
        else:
            o_blame[r] = -1
            o_why[r] = 0
        o_val[r] = worst


@dataclass(frozen=True)
class ArduPilotAnswer:
    """The rule's answer to one sample (``ratio``: each IMU's difference to the primary
    over its threshold, NaN where not compared)."""

    t: float
    flagged: bool
    blamed: int
    ratio: np.ndarray
    events: tuple[BaselineEvent, ...]


class ArduPilotConsistency(StreamingRule):
    """ArduPilot's IMU consistency check over a stream of IMU triads (module docstring).

    Parameters
    ----------
    imus : sequence of str
        IMU names in order; the first is the primary.
    kind : str
    settings : ArduPilotSettings, optional
    """

    name = "ardupilot"

    _answer = ArduPilotAnswer

    def __init__(self, imus: Any, kind: str = "gyro",
                 settings: ArduPilotSettings | None = None) -> None:
        self.imus = tuple(imus)
        self.kind = kind
        self.settings = settings or ArduPilotSettings.defaults(kind)
        if len(self.imus) < 2:
            raise ConfigError(f"ArduPilot baseline: needs two or more IMUs, got "
                              f"{len(self.imus)}")
        s = self.settings
        self._p = np.array([s.threshold, s.third_imu_factor, s.z_factor, s.consistent_for_s])
        self._state = np.array([-np.inf, -1.0])
        self._prev: list[Any] = [False, -1]

    def _advance(self, t: np.ndarray, x: np.ndarray, ok: np.ndarray) -> tuple[Any, ...]:
        N, k = ok.shape
        if k != len(self.imus) or x.shape != (N, k, 3) or t.shape != (N,):
            raise ConfigError(f"ArduPilot baseline: samples {x.shape} / valid {ok.shape} / "
                              f"t {t.shape} do not fit {k} IMUs of three axes")
        ok = ok & np.isfinite(x).all(axis=2)
        flag = np.zeros(N, np.bool_)
        blame = np.full(N, -1, np.int64)
        why = np.zeros(N, np.int64)
        ratio = np.zeros((N, k))
        val = np.zeros(N)
        _ap_kernel(t, np.where(ok[:, :, None], x, 0.0), ok, self._p, self._state, flag,
                   blame, why, ratio, val)
        ev = answer_events(t, flag, blame, why, val, self._prev, self.imus, REASONS, 1.0,
                           "x threshold")
        return flag, blame, ratio, ev

    def result(self, t: np.ndarray, flag: np.ndarray, blame: np.ndarray, ratio: np.ndarray,
               events: Any) -> BaselineResult:
        """A :class:`BaselineResult` of answers (also of answers stepped one by one)."""
        s = self.settings
        unit = "deg/s" if self.kind == "gyro" else "m/s^2"
        f = 1.0 / DPS if self.kind == "gyro" else 1.0
        rule = (f"ArduPilot IMU consistency: each IMU against the primary (IMU 1), "
                f"{s.threshold * f:g} {unit}"
                + (f" (x{s.third_imu_factor:g} from the third IMU, z difference "
                   f"x{s.z_factor:g})" if self.kind == "accel" else "")
                + f", consistent for the last {s.consistent_for_s:g} s"
                + ("" if len(self.imus) >= 3 else "; two IMUs: flags, blames nobody"))
        return BaselineResult(
            name=self.name, rule=rule, kind=self.kind, imus=self.imus, t=np.asarray(t, float),
            flagged=np.asarray(flag, bool), blamed=np.asarray(blame, np.int64),
            measure=np.asarray(ratio, float), measure_unit="x threshold", threshold=1.0,
            events=tuple(events), settings=s.autopilot_units(self.kind), left_out=LEFT_OUT)


def ardupilot_consistency(triads: Triads, settings: ArduPilotSettings | None = None
                          ) -> BaselineResult:
    """ArduPilot's consistency check over a whole set of triads."""
    chk = ArduPilotConsistency(triads.imus, triads.kind, settings)
    return chk.run(triads.t, triads.values, triads.valid)
