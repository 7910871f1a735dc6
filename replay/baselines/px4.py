"""PX4's rule for a bad IMU, run on a log's samples: the EKF2 IMU selector and the validator.

What PX4 does (``/work/shared/AUTOPILOTS.md``, read from PX4-Autopilot's
``src/modules/sensors/voted_sensors_update.cpp``, ``src/modules/ekf2/EKF2Selector.cpp``
and ``src/modules/sensors/data_validator/DataValidator.cpp``), in the terms used here, per
update (one sample of the log) and IMU ``i`` of the ``k`` IMUs:

1. *Inconsistency* (sensors module): the difference of the IMU's three-axis value ``g_i``
   to the mean of all the IMUs' values, ``d_i = g_i − (1/m)·Σ_j g_j`` (PX4 today; older
   versions took the primary, and :attr:`PX4Settings.mean_of` ``"others"`` takes the mean
   of the other IMUs), low-pass filtered per axis ``d̄_i ← 0.95·d̄_i + 0.05·d_i``; the
   inconsistency is ``|d̄_i|``.
2. *Selector* (EKF2): ``A_i ← max(0, A_i + (|d̄_i| − r)·Δt)`` with ``r`` the rate threshold
   (``EKF2_SEL_IMU_RAT`` 7 °/s for gyros, ``EKF2_SEL_IMU_ACC`` 1 m/s² for accelerometers)
   and ``Δt`` the time since the previous update. A fault is declared while the largest
   ``A_i`` exceeds ``EKF2_SEL_IMU_ANG`` (15°) or ``EKF2_SEL_IMU_VEL`` (2 m/s); with three or
   more IMUs the IMU of the largest ``A_i`` is blamed, with two the fault is flagged and
   nobody is blamed.
3. *Validator* (per sensor): confidence drops to zero when its count of repeated values
   passes 100 (stale: :data:`VALIDATOR_STALE_COUNT` says how it counts), or when no sample
   arrives for 20 ms (timeout); an IMU found bad so is blamed at once (the validator
   judges one sensor, so it isolates even with two IMUs) and demoted for the session: it
   leaves the mean.

On logged samples (what is left out, :data:`LEFT_OUT`): the validator's timeout is
checked only where the log's median sample period is at most half the timeout (a 50 Hz log
cannot tell a 20 ms driver gap from its own period), and only against another IMU that did
deliver (a gap in which every IMU is silent is the logger's, not a sensor's); the stale
count is in logged samples (PX4 counts driver samples, usually faster); the driver's error
count and error density are not in logs. Across a log gap longer than
:attr:`PX4Settings.restart_gap_s` the filters start again (the autopilot's state in the
gap is unknown).

:class:`PX4Selector` runs the rule sample by sample (:meth:`PX4Selector.step`) or over a
block (:meth:`PX4Selector.run`); both call the one compiled recursion
(:func:`_px4_kernel`) and give identical answers.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
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

__all__ = [
    "EKF2_SEL_IMU_ACC_MPS2",
    "EKF2_SEL_IMU_ANG_DEG",
    "EKF2_SEL_IMU_RAT_DPS",
    "EKF2_SEL_IMU_VEL_MPS",
    "INCONSISTENCY_FILTER_KEEP",
    "LEFT_OUT",
    "VALIDATOR_EQUAL_TOLERANCE",
    "VALIDATOR_STALE_COUNT",
    "VALIDATOR_TIMEOUT_MS",
    "PX4Answer",
    "PX4Selector",
    "PX4Settings",
    "px4_selector",
    "px4_selector_others",
]

EKF2_SEL_IMU_RAT_DPS = 7.0
"""``EKF2_SEL_IMU_RAT``: gyro inconsistency (°/s) above which the error accumulates."""
EKF2_SEL_IMU_ANG_DEG = 15.0
"""``EKF2_SEL_IMU_ANG``: accumulated gyro error (°) at which a fault is declared."""
EKF2_SEL_IMU_ACC_MPS2 = 1.0
"""``EKF2_SEL_IMU_ACC``: accelerometer inconsistency (m/s²) above which the error
accumulates."""
EKF2_SEL_IMU_VEL_MPS = 2.0
"""``EKF2_SEL_IMU_VEL``: accumulated accelerometer error (m/s) at which a fault is
declared."""
INCONSISTENCY_FILTER_KEEP = 0.95
"""Weight of the old value in the inconsistency low-pass (0.95 old, 0.05 new per update)."""
VALIDATOR_TIMEOUT_MS = 20.0
"""DataValidator's default timeout (ms; 500 ms in HIL)."""
VALIDATOR_STALE_COUNT = 100
"""DataValidator: stale when its count of equal components passes this (the count rises by
one for each component equal to the previous sample's, in axis order, and falls back to zero
at a component that is not: a wholly frozen triad is stale after 34 samples, a triad with one
frozen axis never)."""
VALIDATOR_EQUAL_TOLERANCE = 1e-6
"""DataValidator: two values are "the same" when they differ by less than this (in the
sensor's SI unit, as PX4 keeps them)."""
RESTART_GAP_S = 0.5
"""A log gap (s) after which the filters start again (not a PX4 parameter: the log has no
samples there)."""

LEFT_OUT = (
    "validator error count / error density: driver error counts are not in the samples",
    "validator timeout where the log's median sample period is above half the timeout: "
    "a log at that rate cannot tell a driver gap from its own period",
    "validator stale count is in logged samples (PX4 counts driver samples)",
    "validator stale rule on an IMU triad as PX4 puts it (one validator per IMU); a "
    "frozen single axis never goes stale under it",
    "priority-based switching (get_best): no priorities in the samples; a validator "
    "failure is reported as the blame instead",
)
"""What of PX4's logic :class:`PX4Selector` does not run on logged samples, and why."""

REASONS = ("none", "selector: largest accumulated error (three or more IMUs)",
           "selector: two IMUs, fault not isolated", "validator: stale",
           "validator: timeout")
"""Reason of each answer (index in the kernel's ``why`` output)."""

_P_RATE, _P_ACC, _P_KEEP, _P_TIMEOUT, _P_STALE, _P_GAP, _P_OTHERS, _P_EQ = range(8)


@dataclass(frozen=True)
class PX4Settings:
    """The rule's parameters (SI).

    Attributes
    ----------
    rate_threshold : float
        r: inconsistency above which the error accumulates (rad/s or m/s²).
    fault_threshold : float
        Accumulated error of a fault (rad or m/s).
    filter_keep : float
        Weight of the old value in the inconsistency low-pass.
    timeout_s : float
        Validator timeout (s); 0 or less: not checked.
    stale_count : int
        Repeats of the same value that make a sensor stale.
    mean_of : str
        ``"all"`` (PX4 today) or ``"others"``: what each IMU is compared with.
    restart_gap_s : float
        Log gap after which the filters start again (s).
    """

    rate_threshold: float
    fault_threshold: float
    filter_keep: float = INCONSISTENCY_FILTER_KEEP
    timeout_s: float = VALIDATOR_TIMEOUT_MS * 1e-3
    stale_count: int = VALIDATOR_STALE_COUNT
    mean_of: str = "all"
    restart_gap_s: float = RESTART_GAP_S

    @classmethod
    def defaults(cls, kind: str = "gyro", **kw: Any) -> PX4Settings:
        """PX4's defaults for a gyro or accelerometer set (converted to SI here)."""
        if kind == "gyro":
            return cls(EKF2_SEL_IMU_RAT_DPS * DPS, EKF2_SEL_IMU_ANG_DEG * DPS, **kw)
        if kind == "accel":
            return cls(EKF2_SEL_IMU_ACC_MPS2, EKF2_SEL_IMU_VEL_MPS, **kw)
        raise ConfigError(f"PX4 baseline: unknown sensor kind {kind!r} (gyro or accel)")

    def __post_init__(self) -> None:
        if self.mean_of not in ("all", "others"):
            raise ConfigError(f"PX4 baseline: mean_of {self.mean_of!r} is not 'all' or "
                              "'others'")
        if not (0.0 <= self.filter_keep < 1.0):
            raise ConfigError(f"PX4 baseline: filter_keep {self.filter_keep} not in [0, 1)")

    def autopilot_units(self, kind: str) -> dict[str, Any]:
        """The parameters as PX4 names them, in its units."""
        if kind == "gyro":
            out: dict[str, Any] = {"EKF2_SEL_IMU_RAT_deg_s": self.rate_threshold / DPS,
                                   "EKF2_SEL_IMU_ANG_deg": self.fault_threshold / DPS}
        else:
            out = {"EKF2_SEL_IMU_ACC_m_s2": self.rate_threshold,
                   "EKF2_SEL_IMU_VEL_m_s": self.fault_threshold}
        d = asdict(self)
        out.update({"inconsistency_filter": [self.filter_keep, 1.0 - self.filter_keep],
                    "validator_timeout_ms": 1e3 * self.timeout_s if self.timeout_s > 0
                    else None, "validator_stale_count": self.stale_count,
                    "compared_with": ("mean of all IMUs" if d["mean_of"] == "all"
                                      else "mean of the other IMUs"),
                    "restart_gap_s": self.restart_gap_s})
        return out


@njit(cache=True)
def _px4_kernel(t, x, ok, p, lp, acc, last, same, last_t, demoted, clock,
                o_flag, o_blame, o_why, o_acc, o_val):  # pragma: no cover - compiled
    """The recursion over a block (module docstring); state arrays updated in place.

    t (N,), x (N, k, 3), ok (N, k); p the parameters (``_P_*``); state: lp (k, 3) the
    filtered differences, acc (k,) the accumulated errors, last (k, 3) and last_t (k,)
    each IMU's last sample and its time, same (k,) the repeat counts, demoted (k,) 0 or the
    validator's reason (3 stale, 4 timeout), clock (2,) [time of the previous update,
    started]. Outputs per row: flagged, blamed, why (REASONS index), acc (k,), the value
    reported (the blamed or largest accumulated error).

    One function on purpose (CC 40): it is the per-sample state machine of PX4's selector
    (validator demotion, low-pass, accumulation, blame), compiled by numba as one loop so
    that the block path and ``step`` run the same arithmetic; split into helper calls it
    would need each state array passed and returned per sample.
    """
    N, k = ok.shape
    rate, thr, keep = p[_P_RATE], p[_P_ACC], p[_P_KEEP]
    timeout, stale, gap, others = p[_P_TIMEOUT], p[_P_STALE], p[_P_GAP], p[_P_OTHERS] > 0.5
    eq_tol = p[_P_EQ]
    ref = np.zeros(3)
    for r in range(N):
        tr = t[r]
        dt = 0.0
        if clock[1] > 0.5:
            dt = tr - clock[0]
            if not (0.0 <= dt <= gap):
                dt = 0.0
                for i in range(k):
                    acc[i] = 0.0
                    for a in range(3):
                        lp[i, a] = 0.0
        clock[0] = tr
        clock[1] = 1.0
        any_ok = False
        for i in range(k):
            if ok[r, i]:
                any_ok = True
        # the validator, per IMU
        for i in range(k):
            if ok[r, i]:
                if last_t[i] > -np.inf:
                    # per component in axis order: +1 when equal, back to 0 when not
                    for a in range(3):
                        if abs(x[r, i, a] - last[i, a]) < eq_tol:
                            same[i] += 1
                        else:
                            same[i] = 0
                for a in range(3):
                    last[i, a] = x[r, i, a]
                last_t[i] = tr
                if same[i] > stale and demoted[i] == 0:
                    demoted[i] = 3
            elif (any_ok and timeout > 0.0 and last_t[i] > -np.inf
                  and tr - last_t[i] > timeout and demoted[i] == 0):
                demoted[i] = 4
        # inconsistency to the mean, low-passed; the accumulated error
        m = 0
        for a in range(3):
            ref[a] = 0.0
        for i in range(k):
            if ok[r, i] and demoted[i] == 0:
                m += 1
                for a in range(3):
                    ref[a] += x[r, i, a]
        if m >= 2:
            for i in range(k):
                if not (ok[r, i] and demoted[i] == 0):
                    continue
                s2 = 0.0
                for a in range(3):
                    if others:
                        mean = (ref[a] - x[r, i, a]) / (m - 1)
                    else:
                        mean = ref[a] / m
                    lp[i, a] = keep * lp[i, a] + (1.0 - keep) * (x[r, i, a] - mean)
                    s2 += lp[i, a] * lp[i, a]
                acc[i] = max(0.0, acc[i] + (math.sqrt(s2) - rate) * dt)
        navail = 0
        largest, li, first_bad = -1.0, -1, -1
        for i in range(k):
            o_acc[r, i] = acc[i]
            if demoted[i] == 0:
                navail += 1
                if acc[i] > largest:
                    largest, li = acc[i], i
            elif first_bad < 0:
                first_bad = i
        if first_bad >= 0:
            o_flag[r], o_blame[r], o_why[r] = True, first_bad, demoted[first_bad]
            o_val[r] = acc[first_bad]
        elif largest > thr:
            o_flag[r] = True
            o_blame[r] = li if navail >= 3 else -1
            o_why[r] = 1 if navail >= 3 else 2
            o_val[r] = largest
        else:
            o_flag[r], o_blame[r], o_why[r] = False, -1, 0
            o_val[r] = max(largest, 0.0)


@dataclass(frozen=True)
class PX4Answer:
    """The rule's answer to one sample.

    Attributes
    ----------
    t : float
    flagged : bool
    blamed : int
        0-based IMU (−1: none).
    accumulated : ndarray, shape (k,)
        A_i (rad or m/s).
    events : tuple of BaselineEvent
    """

    t: float
    flagged: bool
    blamed: int
    accumulated: np.ndarray
    events: tuple[BaselineEvent, ...]


class PX4Selector(StreamingRule):
    """PX4's IMU rule over a stream of IMU triads (module docstring).

    Parameters
    ----------
    imus : sequence of str
        The IMU names, in order.
    kind : str
        ``"gyro"`` or ``"accel"``.
    settings : PX4Settings, optional
        Default: PX4's defaults for ``kind``.
    sample_period_s : float, optional
        The log's median sample period: the validator timeout is checked only when it is
        at most half the timeout (two samples or more in a timeout; :data:`LEFT_OUT`).
        None: checked.
    name : str
        The baseline's name in results (``"px4"``; ``"px4-others"`` for the variant that
        compares each IMU with the mean of the others).
    """

    _answer = PX4Answer

    def __init__(self, imus: Any, kind: str = "gyro", settings: PX4Settings | None = None,
                 *, sample_period_s: float | None = None, name: str = "px4") -> None:
        self.name = name
        self.imus = tuple(imus)
        self.kind = kind
        self.settings = settings or PX4Settings.defaults(kind)
        s = self.settings
        k = len(self.imus)
        if k < 2:
            raise ConfigError(f"PX4 baseline: needs two or more IMUs, got {k}")
        # a log sees a driver gap of the timeout only with two or more samples in it
        self.timeout_checked = s.timeout_s > 0 and (sample_period_s is None
                                                    or sample_period_s <= 0.5 * s.timeout_s)
        self._p = np.array([s.rate_threshold, s.fault_threshold, s.filter_keep,
                            s.timeout_s if self.timeout_checked else 0.0,
                            float(s.stale_count), s.restart_gap_s,
                            1.0 if s.mean_of == "others" else 0.0,
                            VALIDATOR_EQUAL_TOLERANCE])
        self._lp = np.zeros((k, 3))
        self._acc = np.zeros(k)
        self._last = np.full((k, 3), np.nan)
        self._same = np.zeros(k, np.int64)
        self._last_t = np.full(k, -np.inf)
        self._demoted = np.zeros(k, np.int64)
        self._clock = np.zeros(2)
        self._prev: list[Any] = [False, -1]
        self.unit = "deg" if kind == "gyro" else "m/s"
        self._to_unit = 1.0 / DPS if kind == "gyro" else 1.0

    def _advance(self, t: np.ndarray, x: np.ndarray, ok: np.ndarray) -> tuple[Any, ...]:
        N, k = ok.shape
        if k != len(self.imus) or x.shape != (N, k, 3) or t.shape != (N,):
            raise ConfigError(f"PX4 baseline: samples {x.shape} / valid {ok.shape} / t "
                              f"{t.shape} do not fit {k} IMUs of three axes")
        ok = ok & np.isfinite(x).all(axis=2)
        flag = np.zeros(N, np.bool_)
        blame = np.full(N, -1, np.int64)
        why = np.zeros(N, np.int64)
        acc = np.zeros((N, k))
        val = np.zeros(N)
        _px4_kernel(t, np.where(ok[:, :, None], x, 0.0), ok, self._p, self._lp, self._acc,
                    self._last, self._same, self._last_t, self._demoted, self._clock,
                    flag, blame, why, acc, val)
        ev = answer_events(t, flag, blame, why, val * self._to_unit, self._prev, self.imus,
                           REASONS, self.settings.fault_threshold * self._to_unit, self.unit)
        return flag, blame, acc, ev

    def result(self, t: np.ndarray, flag: np.ndarray, blame: np.ndarray, acc: np.ndarray,
               events: Any) -> BaselineResult:
        """A :class:`BaselineResult` of answers (also of answers stepped one by one)."""
        s = self.settings
        k = len(self.imus)
        rule = (f"PX4 EKF2 IMU selector: |d̄_i| to the mean of "
                f"{'all' if s.mean_of == 'all' else 'the other'} IMUs, "
                f"accumulated above {s.rate_threshold * self._to_unit:g} "
                f"{'deg/s' if self.kind == 'gyro' else 'm/s^2'}, fault at "
                f"{s.fault_threshold * self._to_unit:g} {self.unit}"
                + ("; blames the largest" if k >= 3 else "; two IMUs: flags, blames nobody")
                + "; validator stale" + (" and timeout" if self.timeout_checked else ""))
        left = LEFT_OUT if not self.timeout_checked else tuple(
            x for x in LEFT_OUT if not x.startswith("validator timeout"))
        return BaselineResult(
            name=self.name, rule=rule, kind=self.kind, imus=self.imus, t=np.asarray(t, float),
            flagged=np.asarray(flag, bool), blamed=np.asarray(blame, np.int64),
            measure=np.asarray(acc, float) * self._to_unit, measure_unit=self.unit,
            threshold=s.fault_threshold * self._to_unit, events=tuple(events),
            settings=s.autopilot_units(self.kind), left_out=left)


def px4_selector(triads: Triads, settings: PX4Settings | None = None, *,
                 name: str = "px4") -> BaselineResult:
    """PX4's rule over a whole set of triads (the validator timeout checked where the
    median sample period allows)."""
    dt = np.diff(triads.t)
    period = float(np.median(dt)) if dt.size else None
    sel = PX4Selector(triads.imus, triads.kind, settings, sample_period_s=period, name=name)
    return sel.run(triads.t, triads.values, triads.valid)


def px4_selector_others(triads: Triads) -> BaselineResult:
    """The variant of older PX4 versions and of the issue's figures: each IMU against the
    mean of the *other* IMUs (``mean_of="others"``), named ``"px4-others"``."""
    return px4_selector(triads, PX4Settings.defaults(triads.kind, mean_of="others"),
                        name="px4-others")
