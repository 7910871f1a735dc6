"""The operating envelope: when the sensors are outside the conditions their model covers.

Shocks, saturation, tumbles and the log's own declared crash or estimator events are
*context*, not sensor faults. Out of the envelope the monitor still detects (and says
so), but it does not exclude a sensor on parity, and the answer carries the reason as a
bit code; no sample is dropped. This module is the one place that decides it, for the
monitor (online, causal, any block size) and for ingest, calibration and diagnose
(offline, through ``replay.envelope``).

Codes (a bitmask, 0 = inside the envelope)
------------------------------------------
- :data:`SHOCK` (1): an impact. The specific force of some IMU exceeds
  ``shock_limit_g`` and every other IMU with an accelerometer exceeds
  ``shock_confirm_g`` within ``confirm_window_s`` (a real impact shakes the whole
  airframe; one accelerometer alone reading large values is that accelerometer's problem).
- :data:`SATURATION` (2): a channel at its range: a gyro axis at ``saturation_fraction`` of
  ``gyro_range_dps`` or repeating one large value ``repeat_samples`` times
  (|value| ≥ ``repeat_min_fraction`` of the range: clipping at a range lower than stated);
  the same for accelerometer axes with ``accel_range_g``. A saturated gyro counts only
  when another independent rate estimate also sees a rate of at least
  ``saturation_confirm_fraction`` of the saturated value, or a shock is under way; a saturated
  accelerometer only when the other accelerometers confirm a shock (``shock_confirm_g``).
  (The confirming rate is a fraction of the clipped value, capped at the range, so that
  clipping at a range lower than stated is confirmed too.)
  A set with a single estimate (one IMU) has nothing to confirm with and takes its
  sensor's word.
- :data:`TUMBLE` (4): the vehicle spins beyond controlled flight. Either every independent
  rate estimate exceeds the tumble limit about some body axis (the larger of
  ``tumble_rate_dps`` and ``tumble_factor`` times the vehicle's own range about it: the
  calibration's ``validated_rate`` or the declared ``vehicle_rate_dps``; a simulated
  manoeuvre at 300 °/s about every axis at once, 520 °/s in all, is not a tumble), or
  the estimates disagree by a *spike* of more
  than ``disagree_spike_dps`` (disagreement above its own slow baseline, time constant
  ``disagree_baseline_s``) while every estimate sees at least ``disagree_context_rate_dps``.
- :data:`DECLARED` (8): inside an interval the log itself declares (crash check, estimator
  variance or failsafe, flip), given as :class:`DeclaredInterval`.
- :data:`RANGE` (16): beyond what the calibration's samples covered: the body turns faster
  about some body axis than ``validated_rate``, or the specific force exceeds
  ``validated_specific_force`` (both from the samples the calibration fitted its error
  model and measured its residual tails on: :func:`covered_rate`,
  :func:`covered_specific_force`). Beyond them the scale-factor, misalignment,
  g-sensitivity and dynamic errors are extrapolated, and the thresholds no longer rest on
  measured residuals. The rate is the *smallest* over the independent estimates, axis by
  axis, and the specific force the smallest over the IMUs, so one faulty sensor reading
  large values cannot raise them. A calibration that states no range (turntable, static
  with stated tolerances, older files) sets no bit. The same holds for a *jolt*: the change
  of specific force from one sample to the next, its magnitude the smallest over the IMUs,
  beyond ``validated_jolt`` (:func:`covered_jolt`). A knock on a bench or an impact rings
  every accelerometer at once (4×MPU9250 at 186.76 s: 140 sd; what the set at rest covered
  is a few sd), while the rate it gives may stay inside the rate range.

Every bit stays set for ``hold_s`` after its condition ends, so that the samples the event
disturbs (ringing, filter transients) stay marked. Offline users may also pad before.

Why these rules cannot hide a sensor fault in calm flight
---------------------------------------------------------
A failing gyro makes the IMUs disagree, and it may read large or clipped values; so no
rule here fires on a gyro's own word when another one can contradict it. "Independent
rate estimates" are the IMU groups (each solves its own body rate), or, for a set not
grouped into IMUs, the leave-one-out subsets of the sensors: a single faulty sensor
corrupts at most one group, so the *minimum* rate over the estimates is what a healthy
sensor confirms. Tumble needs every estimate above the limit; the disagreement rule needs
a fast rotation seen by every estimate and a sudden jump of the disagreement (a step or a
ramp has a slow baseline that absorbs it); gyro saturation needs a second estimate at a
large rate or a shock; shocks need every accelerometer. A fault that occurs *during* a
real shock or tumble is masked from exclusion for that period (and ``hold_s`` after):
that is the stated price, bounded by the duration of the marked periods, and detection
keeps running there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from itertools import combinations

import numpy as np

from fdi.errors import ConfigError
from fdi.units import DPS, G0

__all__ = [
    "DECLARED",
    "RANGE",
    "REASONS",
    "SATURATION",
    "SHOCK",
    "TUMBLE",
    "DeclaredInterval",
    "EnvelopeSettings",
    "EnvelopeTracker",
    "covered_jolt",
    "covered_rate",
    "covered_specific_force",
    "independent_estimates",
    "reason_names",
]

SHOCK = 1
"""An impact: specific force beyond the shock limit, confirmed by every accelerometer."""
SATURATION = 2
"""A gyro or accelerometer channel at its range (or clipping), confirmed."""
TUMBLE = 4
"""The vehicle spins beyond controlled flight (every rate estimate fast, or a
disagreement spike during a fast rotation)."""
DECLARED = 8
"""Inside a crash or estimator event the log declares."""
RANGE = 16
"""Beyond what the calibration's samples covered: turning faster about some body axis, or a
larger specific force or jolt felt by every IMU."""

REASONS: dict[int, str] = {SHOCK: "shock", SATURATION: "saturation", TUMBLE: "tumble",
                           DECLARED: "declared", RANGE: "range"}
"""Name of each code bit."""


def reason_names(code: int) -> tuple[str, ...]:
    """Names of the bits set in ``code`` (``()`` for 0), lowest bit first.

    Bits this version does not know are named ``"bit<k>"`` (never raises).
    """
    try:
        c = int(code)
    except (TypeError, ValueError, OverflowError):
        return ()
    out = []
    k = 0
    while c > 0 and k < 64:
        b = 1 << k
        if c & b:
            out.append(REASONS.get(b, f"bit{k}"))
        k += 1
    return tuple(out)


@dataclass(frozen=True)
class DeclaredInterval:
    """A time span the log declares out of the envelope: ``[t0_s, t1_s]`` (s, log clock).

    ``t1_s`` may be ``inf`` (to the end of the recording) and equal ``t0_s`` (an instant,
    held for ``hold_s``). ``reason`` is the log's own wording (``"ERR CRASH_CHECK 1:
    crash"``).
    """

    t0_s: float
    t1_s: float
    reason: str = ""


@dataclass(frozen=True)
class EnvelopeSettings:
    """The limits of the operating envelope (module docstring); units in the names.

    Defaults suit a multirotor with MEMS IMUs (±2000 °/s gyros, ±16 g accelerometers, as
    ArduPilot and PX4 configure the InvenSense parts).
    """

    shock_limit_g: float = 4.0
    """Specific force (g) of one IMU that makes an impact ..."""
    shock_confirm_g: float = 2.0
    """... when every other accelerometer exceeds this (g) within ``confirm_window_s``."""
    confirm_window_s: float = 0.1
    """Window (s) within which the IMUs must confirm one another (impacts reach two
    accelerometers a few samples apart at 50 Hz)."""
    gyro_range_dps: float = 2000.0
    """Full scale of the gyros (°/s)."""
    accel_range_g: float = 16.0
    """Full scale of the accelerometers (g)."""
    saturation_fraction: float = 0.95
    """A channel at or beyond this fraction of its range is saturated."""
    repeat_samples: int = 3
    """Identical consecutive values that count as clipping ..."""
    repeat_min_fraction: float = 0.25
    """... when their magnitude is at least this fraction of the range."""
    saturation_confirm_fraction: float = 0.5
    """A saturated gyro counts when another estimate sees this fraction of its value
    (capped at the range)."""
    tumble_rate_dps: float = 400.0
    """Least rate (°/s) about one body axis beyond which, seen by every estimate, the
    vehicle tumbles; the limit rises with the vehicle's own range (``tumble_factor``)."""
    tumble_factor: float = 1.25
    """The tumble limit about each body axis is the larger of ``tumble_rate_dps`` and this
    times the vehicle's range about it: the calibration's covered rate
    (``validated_rate``) or the declared ``vehicle_rate_dps``, whichever is larger."""
    vehicle_rate_dps: float = 0.0
    """Declared largest body rate (°/s) of controlled flight about any axis (0: not
    declared): a vehicle that manoeuvres at 300 °/s about each axis does not tumble at
    400 °/s about one of them."""
    disagree_spike_dps: float = 100.0
    """Jump (°/s) of the disagreement between estimates above its slow baseline ..."""
    disagree_context_rate_dps: float = 200.0
    """... that counts while every estimate sees at least this rate (°/s)."""
    disagree_baseline_s: float = 2.0
    """Time constant (s) of the disagreement's slow baseline."""
    hold_s: float = 0.5
    """Each bit stays set this long (s) after its condition ends."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ConfigError(f"envelope setting {f.name}: expected a finite number, "
                                  f"got {v!r}")
            if v < 0:
                raise ConfigError(f"envelope setting {f.name}: must be >= 0, got {v!r}")
        for name in ("gyro_range_dps", "accel_range_g", "disagree_baseline_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"envelope setting {name}: must be > 0")
        if int(self.repeat_samples) != self.repeat_samples or self.repeat_samples < 2:
            raise ConfigError(f"envelope setting repeat_samples: expected an integer >= 2, "
                              f"got {self.repeat_samples!r}")
        if not 0 < self.saturation_fraction <= 1:
            raise ConfigError("envelope setting saturation_fraction: must be in (0, 1]")

    def to_dict(self) -> dict[str, float]:
        """JSON-ready."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def independent_estimates(H: np.ndarray, groups: Sequence[Sequence[int]] | None
                          ) -> tuple[tuple[int, ...], ...]:
    """Sensor subsets that each solve the body rate on their own (rank 3).

    The IMU groups when given (groups that cannot solve 3 axes are left out); otherwise
    the leave-one-out subsets of all sensors when there are at least four (one faulty
    sensor then spoils at most one estimate), else all sensors as one estimate.
    """
    H = np.asarray(H, float)
    n = H.shape[0]

    def ok(g: Sequence[int]) -> bool:
        return len(g) >= 3 and bool(np.all(np.isfinite(H[list(g)]))) \
            and np.linalg.matrix_rank(H[list(g)]) == 3

    if groups:
        out = tuple(tuple(int(i) for i in g) for g in groups if ok(g))
        if out:
            return out
    if n >= 4:
        loo = tuple(c for c in combinations(range(n), n - 1) if ok(c))
        if loo:
            return loo
    return (tuple(range(n)),) if n else ()


class EnvelopeTracker:
    """Envelope codes of a stream of samples, causal, with state across blocks.

    Feeding a recording whole or in blocks of any size gives identical codes.

    Parameters
    ----------
    settings : EnvelopeSettings, optional
    H : ndarray, shape (n, 3)
        Calibrated input axes of the monitored gyros (rows).
    groups : sequence of sequence of int, optional
        Sensor indices (0-based) of each IMU (``Flight.imu_groups()``); see
        :func:`independent_estimates`.
    declared : sequence of DeclaredInterval
        Intervals the log declares out of the envelope.
    validated_rate : ndarray, shape (3,), optional
        The calibration's covered rate per body axis (rad/s, :func:`covered_rate`); None:
        no :data:`RANGE` bit.
    validated_specific_force : float, optional
        The calibration's covered specific force (m/s², :func:`covered_specific_force`);
        None: not checked.
    validated_jolt : float, optional
        The calibration's covered jolt (m/s² from one sample to the next,
        :func:`covered_jolt`); None: not checked.
    """

    def __init__(self, settings: EnvelopeSettings | None = None, *, H: np.ndarray,
                 groups: Sequence[Sequence[int]] | None = None,
                 declared: Sequence[DeclaredInterval] = (),
                 validated_rate: np.ndarray | None = None,
                 validated_specific_force: float | None = None,
                 validated_jolt: float | None = None) -> None:
        self.settings = settings if settings is not None else EnvelopeSettings()
        H = np.asarray(H, float)
        if H.ndim != 2 or H.shape[1] != 3 or H.shape[0] < 1:
            raise ConfigError(f"envelope: H must be (n, 3), got {H.shape}")
        self.n = H.shape[0]
        self.estimates = independent_estimates(H, groups)
        self._solvers = [np.linalg.pinv(H[list(g)]) for g in self.estimates]
        self.declared = tuple(declared)
        self.validated_rate = None
        if validated_rate is not None:
            v = np.asarray(validated_rate, float).reshape(-1)
            if v.shape != (3,) or np.isnan(v).any() or (v < 0).any():
                raise ConfigError(f"envelope: validated_rate must be 3 rates >= 0 (rad/s), "
                                  f"got {validated_rate!r}")
            self.validated_rate = v
        f = validated_specific_force
        if f is not None and not (isinstance(f, int | float) and f >= 0):
            raise ConfigError(f"envelope: validated_specific_force must be a number >= 0 "
                              f"(m/s^2), got {f!r}")
        self.validated_specific_force = None if f is None else float(f)
        j = validated_jolt
        if j is not None and not (isinstance(j, int | float) and j >= 0):
            raise ConfigError(f"envelope: validated_jolt must be a number >= 0 (m/s^2), "
                              f"got {j!r}")
        self.validated_jolt = None if j is None else float(j)
        self.reset()

    def reset(self) -> None:
        """Forget the past (a new recording)."""
        self._last = {b: -np.inf for b in REASONS}       # last time each condition held
        self._last_big = -np.inf                         # some IMU above shock_limit_g
        self._last_conf: np.ndarray | None = None        # per IMU: above shock_confirm_g
        self._run_val = np.full(self.n, np.nan)          # value of the current repeat run
        self._run_len = np.zeros(self.n, np.int64)
        self._acc_run_val: np.ndarray | None = None
        self._acc_run_len: np.ndarray | None = None
        self._base: np.ndarray | None = None             # disagreement baseline (pairs, 3)
        self._t_prev = np.nan
        self._t_prev_base = np.nan
        self._acc_prev: np.ndarray | None = None         # last specific force (k, 3)

    # -- pieces -----------------------------------------------------------------------
    def _rates(self, rates: np.ndarray) -> np.ndarray:
        """Body rate of each estimate, shape (E, B, 3)."""
        out = []
        for g, P in zip(self.estimates, self._solvers, strict=True):
            out.append(rates[:, list(g)] @ P.T)
        return np.stack(out) if out else np.zeros((0, rates.shape[0], 3))

    def _repeats(self, x: np.ndarray, big: np.ndarray, val: np.ndarray, ln: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per column: True where the value has repeated ``repeat_samples`` times in a row
        (counting across blocks) and is large; returns (mask (B, m), run value, run length)."""
        B = x.shape[0]
        prev = np.vstack([val[None, :], x[:-1]])
        brk = ~((x == prev) & np.isfinite(x))                     # a new run starts here
        idx = np.arange(B)[:, None]
        last = np.maximum.accumulate(np.where(brk, idx, -1), axis=0)
        length = np.where(last >= 0, idx - last + 1, ln[None, :] + idx + 1)
        out = (length >= int(self.settings.repeat_samples)) & big
        return out, x[-1].copy(), length[-1].astype(np.int64)

    def _held(self, t: np.ndarray, cond: np.ndarray, bit: int) -> np.ndarray:
        """True where ``cond`` held within ``hold_s`` before; updates the state."""
        last = np.maximum.accumulate(np.where(cond, t, -np.inf))
        last = np.maximum(last, self._last[bit])
        self._last[bit] = float(last[-1])
        return (t - last) <= self.settings.hold_s

    # -- the update ---------------------------------------------------------------------
    def update(self, t: np.ndarray, rates: np.ndarray, accel: np.ndarray | None = None
               ) -> np.ndarray:
        """Codes of one block of samples.

        Parameters
        ----------
        t : ndarray, shape (B,)
            Sample times (s), non-decreasing across calls.
        rates : ndarray, shape (B, n)
            Calibrated gyro outputs (rad/s, along each calibrated axis); NaN = no sample.
        accel : ndarray, shape (B, k, 3), optional
            Specific force of each of the k IMUs with an accelerometer (m/s²).

        Returns
        -------
        ndarray of int64, shape (B,)
            Bitmask of :data:`SHOCK`, :data:`SATURATION`, :data:`TUMBLE`, :data:`DECLARED`,
            :data:`RANGE`.
            Never raises on bad numbers (NaN/inf count as no evidence, except that inf is
            at the range).
        """
        t = np.asarray(t, float).reshape(-1)
        B = t.shape[0]
        codes = np.zeros(B, np.int64)
        if B == 0:
            return codes
        rates = np.asarray(rates, float).reshape(B, self.n)
        # a time that is not finite or goes back is replaced by the last good one
        t = np.where(np.isfinite(t), t, np.nan)
        if np.isnan(t).all() and not np.isfinite(self._t_prev):
            t = np.zeros(B)
        t = np.fmax.accumulate(np.concatenate([[self._t_prev], t]))[1:]
        t = np.where(np.isnan(t), 0.0, t)
        self._t_prev = float(t[-1])
        with np.errstate(all="ignore"):
            w = self._rates(np.where(np.isfinite(rates), rates, np.nan))   # (E, B, 3)
            wmag = np.linalg.norm(w, axis=2)                               # (E, B)
            wmin = np.min(np.where(np.isnan(wmag), -np.inf, wmag), axis=0) if len(wmag) \
                else np.full(B, -np.inf)
            shock_now = self._shock(t, accel)
            shock = self._held(t, shock_now, SHOCK)
            sat_now = self._saturation(rates, accel, wmag, shock_now)
            sat = self._held(t, sat_now, SATURATION)
            tum_now = self._tumble(t, w, wmin)
            tum = self._held(t, tum_now, TUMBLE)
            dec = self._declared(t)
            rng = self._held(t, self._range(w, accel), RANGE)
        codes |= np.where(rng, RANGE, 0)
        codes |= np.where(shock, SHOCK, 0)
        codes |= np.where(sat, SATURATION, 0)
        codes |= np.where(tum, TUMBLE, 0)
        codes |= np.where(dec, DECLARED, 0)
        return codes

    def _shock(self, t: np.ndarray, accel: np.ndarray | None) -> np.ndarray:
        s = self.settings
        B = t.shape[0]
        if accel is None:
            return np.zeros(B, bool)
        a = np.asarray(accel, float).reshape(B, -1, 3)
        k = a.shape[1]
        if k == 0:
            return np.zeros(B, bool)
        f = np.linalg.norm(a, axis=2)                                      # (B, k)
        f = np.where(np.isnan(f), 0.0, f)
        big = (f > s.shock_limit_g * G0).any(axis=1)
        last_big = np.maximum(np.maximum.accumulate(np.where(big, t, -np.inf)), self._last_big)
        self._last_big = float(last_big[-1])
        if self._last_conf is None or self._last_conf.shape[0] != k:
            self._last_conf = np.full(k, -np.inf)
        conf = f > s.shock_confirm_g * G0
        last_conf = np.maximum(np.maximum.accumulate(np.where(conf, t[:, None], -np.inf),
                                                     axis=0), self._last_conf)
        self._last_conf = last_conf[-1].copy()
        win = s.confirm_window_s
        return ((t - last_big) <= win) & np.all((t[:, None] - last_conf) <= win, axis=1)

    def _saturation(self, rates: np.ndarray, accel: np.ndarray | None, wm: np.ndarray,
                    shock_now: np.ndarray) -> np.ndarray:
        s = self.settings
        B = rates.shape[0]
        rng = s.gyro_range_dps * DPS
        a = np.abs(rates)
        at_range = a >= s.saturation_fraction * rng                        # inf counts
        rep, self._run_val, self._run_len = self._repeats(
            rates, a >= s.repeat_min_fraction * rng, self._run_val, self._run_len)
        sat_sensor = at_range | rep                                        # (B, n)
        one = len(self.estimates) <= 1
        if one:
            gyro = sat_sensor.any(axis=1)
        else:
            # confirmed by an estimate that does not use the saturated sensor
            wmag_ok = np.zeros(B, bool)
            level = np.where(sat_sensor, np.minimum(a, rng), 0.0)            # (B, n)
            for e, g in enumerate(self.estimates):
                others = [i for i in range(self.n) if i not in g]
                if not others:
                    continue
                top = level[:, others].max(axis=1)
                wmag_ok |= (top > 0) & (wm[e] >= s.saturation_confirm_fraction * top)
            gyro = wmag_ok | (sat_sensor.any(axis=1) & shock_now)
        acc_sat = np.zeros(B, bool)
        if accel is not None:
            ac = np.asarray(accel, float).reshape(B, -1)
            if ac.shape[1]:
                arng = s.accel_range_g * G0
                aa = np.abs(ac)
                if self._acc_run_val is None or self._acc_run_val.shape[0] != ac.shape[1]:
                    self._acc_run_val = np.full(ac.shape[1], np.nan)
                    self._acc_run_len = np.zeros(ac.shape[1], np.int64)
                rep_a, self._acc_run_val, self._acc_run_len = self._repeats(
                    ac, aa >= s.repeat_min_fraction * arng, self._acc_run_val,
                    self._acc_run_len)
                hit = ((aa >= s.saturation_fraction * arng) | rep_a).any(axis=1)
                acc_sat = hit & (shock_now | (ac.shape[1] <= 3))
        return gyro | acc_sat

    def tumble_limit(self) -> np.ndarray:
        """The tumble limit about each body axis (rad/s), shape (3,): the larger of
        ``tumble_rate_dps`` and ``tumble_factor`` times the vehicle's range (its calibrated
        ``validated_rate``, or the declared ``vehicle_rate_dps``)."""
        s = self.settings
        rng = np.full(3, s.vehicle_rate_dps * DPS)
        if self.validated_rate is not None:
            rng = np.maximum(rng, np.where(np.isfinite(self.validated_rate),
                                           self.validated_rate, 0.0))
        return np.maximum(s.tumble_rate_dps * DPS, s.tumble_factor * rng)

    def _tumble(self, t: np.ndarray, w: np.ndarray, wmin: np.ndarray) -> np.ndarray:
        s = self.settings
        B = t.shape[0]
        # every estimate beyond the limit about some body axis (the axis floor: a healthy
        # manoeuvre of the vehicle's own range about each axis at once is not a tumble)
        fast = np.any(_axis_floor(w) > self.tumble_limit(), axis=1)
        E = w.shape[0]
        if E < 2:
            return fast
        pairs = list(combinations(range(E), 2))
        d = np.stack([w[i] - w[j] for i, j in pairs], axis=1)              # (B, P, 3)
        d = np.where(np.isfinite(d), d, np.nan)
        P = len(pairs)
        if self._base is None:
            self._base = np.full(P * 3, np.nan)
        flat = d.reshape(B, P * 3)
        before = np.empty_like(flat)             # baseline before each sample's update
        base = [float(v) for v in self._base]
        tprev = self._t_prev_base
        tau = s.disagree_baseline_s
        alphas = (1.0 - np.exp(-np.maximum(np.diff(np.concatenate([[tprev], t])), 0.0) / tau)
                  ).tolist()
        rows = flat.tolist()
        for i in range(B):
            row = rows[i]
            a = alphas[i] if alphas[i] == alphas[i] else 0.0       # NaN (first ever): 0
            for k in range(P * 3):
                x = row[k]
                b = base[k]
                if b != b:
                    b = x
                before[i, k] = b
                if x == x:
                    base[k] = b + a * (x - b)
        self._base = np.asarray(base, float)
        self._t_prev_base = float(t[-1])
        dev = np.linalg.norm((flat - before).reshape(B, P, 3), axis=2)
        spike = np.any(dev > s.disagree_spike_dps * DPS, axis=1)
        context = wmin >= s.disagree_context_rate_dps * DPS
        return fast | (spike & context)

    def _range(self, w: np.ndarray, accel: np.ndarray | None) -> np.ndarray:
        """True where the axis floor of the rate exceeds the validated rate on some axis, or
        the specific force or the jolt every IMU feels exceeds the validated one."""
        B = w.shape[1]
        out = np.zeros(B, bool)
        if self.validated_rate is not None:
            out |= np.any(_axis_floor(w) > self.validated_rate, axis=1)
        if accel is None:
            return out
        a = np.asarray(accel, float).reshape(B, -1, 3)
        if self.validated_specific_force is not None:
            out |= _force_floor(a) > self.validated_specific_force
        if self.validated_jolt is not None:
            prev = self._acc_prev if (self._acc_prev is not None
                                      and self._acc_prev.shape == a.shape[1:]) else None
            out |= _jolt_floor(a, prev) > self.validated_jolt
            self._acc_prev = a[-1].copy()
        return out

    def _declared(self, t: np.ndarray) -> np.ndarray:
        out = np.zeros(t.shape[0], bool)
        h = self.settings.hold_s
        for d in self.declared:
            t0 = d.t0_s if math.isfinite(d.t0_s) else -math.inf
            t1 = d.t1_s if not math.isnan(d.t1_s) else math.inf
            out |= (t >= t0) & (t <= t1 + h)
        return out


def _axis_floor(w: np.ndarray) -> np.ndarray:
    """Per body axis, the smallest |rate| over the independent estimates: (E, B, 3) → (B, 3)
    (rad/s); NaN counts as no evidence (0), no estimate gives 0."""
    if w.shape[0] == 0:
        return np.zeros(w.shape[1:])
    with np.errstate(invalid="ignore"):
        a = np.where(np.isfinite(w), np.abs(w), np.where(np.isnan(w), 0.0, np.inf))
    return np.min(a, axis=0)


def _force_floor(accel: np.ndarray) -> np.ndarray:
    """The smallest specific-force magnitude over the IMUs: (B, k, 3) → (B,) m/s²; NaN
    counts as 0 (no evidence), no IMU gives 0."""
    if accel.shape[1] == 0:
        return np.zeros(accel.shape[0])
    with np.errstate(invalid="ignore"):
        f = np.linalg.norm(accel, axis=2)
    return np.min(np.where(np.isnan(f), 0.0, f), axis=1)


def _jolt_floor(accel: np.ndarray, prev: np.ndarray | None = None) -> np.ndarray:
    """The smallest change of specific force from the previous sample over the IMUs:
    (B, k, 3) → (B,) m/s²; ``prev`` (k, 3) is the sample before the block (None: the first
    sample has no change); NaN or inf counts as 0 (no evidence), no IMU gives 0."""
    B = accel.shape[0]
    if accel.shape[1] == 0 or B == 0:
        return np.zeros(B)
    first = accel[:1] if prev is None else np.asarray(prev, float)[None]
    with np.errstate(invalid="ignore"):
        d = np.linalg.norm(np.diff(np.concatenate([first, accel]), axis=0), axis=2)
    return np.min(np.where(np.isfinite(d), d, 0.0), axis=1)


def covered_jolt(accel: np.ndarray, used: np.ndarray | None = None) -> float:
    """The jolt a calibration covered: the largest over the samples ``used`` of the
    smallest change of specific force from the sample before over the IMUs (what the
    :data:`RANGE` bit compares), m/s² per sample.

    Parameters
    ----------
    accel : ndarray, shape (N, k, 3)
        Specific force of each IMU (m/s²), consecutive samples.
    used : ndarray of bool, shape (N,), optional
        The samples the calibration fitted its model on (default: all); a jolt counts
        where its sample and the one before were both used.
    """
    a = np.asarray(accel, float)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ConfigError(f"covered_jolt: accel must be (N, k, 3), got {a.shape}")
    j = _jolt_floor(a)
    if used is not None:
        u = np.asarray(used, bool)
        j = j[u & np.concatenate([[True], u[:-1]])]     # the sample before was used too
    return float(np.max(j)) if j.size and a.shape[1] else 0.0


def covered_specific_force(accel: np.ndarray, used: np.ndarray | None = None) -> float:
    """The specific force a calibration covered: the largest over the samples ``used`` of
    the smallest magnitude over the IMUs (what the :data:`RANGE` bit compares), m/s².

    Parameters
    ----------
    accel : ndarray, shape (N, k, 3)
        Specific force of each IMU (m/s²).
    used : ndarray of bool, shape (N,), optional
        The samples the calibration fitted its model on (default: all).
    """
    a = np.asarray(accel, float)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ConfigError(f"covered_specific_force: accel must be (N, k, 3), got {a.shape}")
    if used is not None:
        a = a[np.asarray(used, bool)]
    a = a[np.all(np.isfinite(a), axis=(1, 2))]
    return float(np.max(_force_floor(a))) if a.shape[0] and a.shape[1] else 0.0


def covered_rate(H: np.ndarray, groups: Sequence[Sequence[int]] | None, rates: np.ndarray,
                 used: np.ndarray | None = None) -> np.ndarray:
    """The rate range a calibration covered: per body axis, the largest over the samples
    ``used`` of the smallest |rate| over the independent estimates (the quantity the
    :data:`RANGE` bit compares), shape (3,) rad/s.

    Parameters
    ----------
    H : ndarray, shape (n, 3)
        Calibrated axes.
    groups : sequence of sequence of int, optional
        IMU groups (:func:`independent_estimates`).
    rates : ndarray, shape (N, n)
        Calibrated gyro outputs (rad/s); NaN = no sample.
    used : ndarray of bool, shape (N,), optional
        The samples the calibration fitted its model on (default: all).
    """
    H = np.asarray(H, float)
    rates = np.asarray(rates, float)
    est = independent_estimates(H, groups)
    if used is not None:
        rates = rates[np.asarray(used, bool)]
    rows = np.all(np.isfinite(rates), axis=1)
    rates = rates[rows]
    if not est or rates.shape[0] == 0:
        return np.zeros(3)
    w = np.stack([rates[:, list(g)] @ np.linalg.pinv(H[list(g)]).T for g in est])
    return np.max(_axis_floor(w), axis=0)
