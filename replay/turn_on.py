"""The per-power-up part of a calibration: the turn-on bias on a new flight.

A calibration splits into what holds across power-ups (axes, scale factors, a lag that
belongs to the firmware) and what does not: the turn-on bias of a MEMS gyro changes at
every power-up (two erle flights of one day: IMU2's fitted y bias −0.65 and +0.38 °/s).
PX4 and ArduPilot calibrate the gyro bias at every boot while the vehicle is still
(``AUTOPILOTS.md``). On a flight other than the calibration's own, the monitor chain does
the same (:func:`turn_on_for_flight`):

1. **At rest before take-off** (:func:`find_rest`): the log is cut into windows of
   :data:`REST_WINDOW_S`; a window is still when every gyro and every accelerometer axis
   is quiet (sample sd at most :data:`REST_GYRO_SD_DPS` and :data:`REST_ACCEL_SD`), the
   body rate the window's means give is below :data:`REST_RATE_DPS`, the specific force
   is within :data:`REST_G_TOLERANCE` of 1 g and the means do not move from the window
   before (gyros: by more than 4 sd of the difference of two window means, at least
   :data:`REST_GYRO_STEP_DPS`; accelerometers: by :data:`REST_ACCEL_STEP`, a tilt of about
   a degree). Take-off is the first window far outside rest (rate above
   :data:`MOTION_RATE_DPS`, gyro sd above :data:`MOTION_GYRO_SD_DPS` or accelerometer sd
   above :data:`MOTION_ACCEL_SD`); the rest stretch is the longest run of still windows
   before it, at least :data:`MIN_REST_S` long. The thresholds are physical (no
   calibration noise level: the motors may idle at rest), and nothing depends on a file's
   times.
2. **The bias from the stretch**: ``b_i = mean(SF_i·u_i)`` over the stretch (the body at
   rest: ω = 0 up to the Earth rate, 15.04 °/h, which the parity does not see and which
   moves ω̂ by at most that much); its sd is the larger of the white-noise sd of the mean
   and the scatter of the window means (colour up to a window). The estimate replaces the
   calibration's bias and its sd the bias sd (the monitor's bias-uncertainty inflation β,
   :mod:`fdi.reconstruction`).
3. **No stretch**: the biases stay as calibrated, and the thresholds and protection level
   cover a nominal bias bound (ARAIM's b_nom, :mod:`fdi.bias_bound`): per sensor
   :data:`BOUND_SIGMAS` times the calibration's ``bias_turn_on_sd`` (the run-to-run spread
   of several flights calibrated together), else ``--bias-bound-dps``, else (only when
   asked, ``mode="bound"`` or ``"rest"``) :data:`DEFAULT_BIAS_BOUND_DPS`; which one is
   said. In ``mode="auto"`` a calibration that states no spread, with no bound given, is
   used as calibrated: a guessed bound raises the thresholds by the size of the faults
   they must see (the baselines campaign: 2 °/s steps on simulated four-IMU flights went
   from 24 of 24 detected within 5 s to 0 of 24 under the 1 °/s default).

On the calibration's own power-up (the flight identity it records,
:mod:`calibration.inflight.timing`: that flight, or a part of the same log) the bias is the
one fitted on it: nothing is changed. A turntable calibration (no
flight recorded) that states no run-to-run spread is used as calibrated unless asked
(``mode="rest"`` or ``"bound"``).

In a recorded flight the rest stretch lies at the start and its samples are monitored with
the estimate made from them (as a boot calibration would have been); a live run would
start monitoring at its end.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.units import DPS

__all__ = ["BOUND_SIGMAS", "DEFAULT_BIAS_BOUND_DPS", "MIN_REST_S", "MODES", "MOTION_ACCEL_SD",
           "MOTION_GYRO_SD_DPS", "MOTION_RATE_DPS", "REST_ACCEL_SD", "REST_ACCEL_STEP",
           "REST_GYRO_SD_DPS",
           "REST_GYRO_STEP_DPS", "REST_G_TOLERANCE", "REST_RATE_DPS", "REST_WINDOW_S",
           "RestStretch", "TurnOn", "apply_turn_on", "estimate_rest_bias", "find_rest",
           "same_power_up", "turn_on_for_flight"]

G0 = 9.80665
"""Standard gravity (m/s²)."""
REST_WINDOW_S = 1.0
"""Length of the windows the stillness is judged on (s)."""
MIN_REST_S = 2.0
"""Shortest rest stretch a bias is estimated from (s)."""
REST_GYRO_SD_DPS = 5.0
"""A still window's gyro sample sd is at most this (°/s): idling motors vibrate (erle 83
at rest: up to 1.7 °/s), handling moves by tens of °/s."""
REST_ACCEL_SD = 1.0
"""A still window's accelerometer sample sd (m/s², per axis) is at most this."""
REST_RATE_DPS = 3.0
"""A still window's body rate (from its means, °/s) is below this."""
REST_GYRO_STEP_DPS = 0.1
"""Least change of a gyro's window mean (°/s) that counts as movement (ArduPilot's boot
calibration asks two successive averages to agree within 0.1 °/s)."""
REST_G_TOLERANCE = 2.5
"""A still window's specific force is within this of 1 g (m/s²; loose: the accelerometers
of a log are not calibrated, erle 41's IMU1 reads 1.6 m/s² below g at rest)."""
REST_ACCEL_STEP = 0.2
"""A still window's mean specific force moves by less than this from the window before
(m/s²: a tilt of about 1.2°)."""
MOTION_RATE_DPS = 10.0
"""A window turning faster than this (°/s, from its means) has left rest."""
MOTION_GYRO_SD_DPS = 10.0
"""A window whose gyro sample sd passes this (°/s) has left rest (take-off, handling)."""
MOTION_ACCEL_SD = 2.0
"""A window whose accelerometer sample sd passes this (m/s²) has left rest."""
BOUND_SIGMAS = 3.0
"""The nominal bias bound is this many run-to-run sd per sensor (99.7 % of power-ups of a
Gaussian spread)."""
DEFAULT_BIAS_BOUND_DPS = 1.0
"""Nominal bias bound (°/s per gyro) when the calibration states no run-to-run spread and
none is given: the size of the bias change measured between two flights of one airframe
(erle, IMU2 y: about 1 °/s); give ``--bias-bound-dps`` for your sensors."""
MODES = ("auto", "rest", "bound", "off")
"""``auto``: on another flight than the calibration's, the rest estimate, else the bound;
``rest``: the rest estimate where the log has a stretch, else the bound; ``bound``: the
bound only; ``off``: the biases as calibrated."""


@dataclass(frozen=True)
class RestStretch:
    """A stretch at rest before take-off.

    Attributes
    ----------
    t0_s, t1_s : float
        First and last sample time of the stretch (s).
    samples : int
    takeoff_s : float or None
        Time of the first window that left rest (None: the log never does).
    judged_on : str
        ``"gyros and accelerometers"`` or ``"gyros"`` (no accelerometer triad).
    """

    t0_s: float
    t1_s: float
    samples: int
    takeoff_s: float | None
    judged_on: str


@dataclass(frozen=True)
class TurnOn:
    """What the monitor chain did about the per-power-up bias (module docstring).

    Attributes
    ----------
    method : str
        ``"rest"`` (estimated at rest), ``"bound"`` (a nominal bias bound covered),
        ``"calibrated"`` (the biases as calibrated).
    reason : str
        Why, in a sentence.
    stretch : RestStretch or None
    bias, bias_sd : tuple of float
        The biases the monitor uses and their sd (SI).
    shift : tuple of float
        ``bias − calibrated bias`` (SI).
    bound : tuple of float
        Nominal bias bound per sensor (SI; empty unless ``method == "bound"``).
    bound_source : str
        Where the bound comes from (``bias_turn_on_sd``, ``--bias-bound-dps``, default).
    kind : str
    """

    method: str
    reason: str
    stretch: RestStretch | None
    bias: tuple[float, ...]
    bias_sd: tuple[float, ...]
    shift: tuple[float, ...]
    bound: tuple[float, ...] = ()
    bound_source: str = ""
    kind: str = "gyro"

    def text(self, names: Any = ()) -> str:
        """One line for the command's output."""
        conv, unit = (DPS, "deg/s") if self.kind == "gyro" else (1.0, "m/s^2")
        if self.method == "rest":
            st = self.stretch
            big = int(np.argmax(np.abs(self.shift))) if self.shift else 0
            who = names[big] if big < len(names) else f"sensor {big + 1}"
            return (f"turn-on bias: estimated at rest {st.t0_s:.2f}-{st.t1_s:.2f} s "
                    f"({st.samples} samples, judged on the {st.judged_on}); largest change "
                    f"from the calibration {self.shift[big] / conv:+.3g} {unit} ({who}), "
                    f"sd {max(self.bias_sd) / conv:.2g} {unit}")
        if self.method == "bound":
            return (f"turn-on bias: {self.reason}; thresholds and protection level cover a "
                    f"nominal bias bound of up to {max(self.bound) / conv:.3g} {unit} per "
                    f"sensor ({self.bound_source})")
        return f"turn-on bias: as calibrated ({self.reason})"

    def to_dict(self) -> dict[str, Any]:
        """For the report."""
        conv = DPS if self.kind == "gyro" else 1.0
        unit = "deg_s" if self.kind == "gyro" else "m_s2"
        st = self.stretch
        return {"method": self.method, "reason": self.reason,
                "rest": None if st is None else st.__dict__.copy(),
                f"bias_{unit}": [b / conv for b in self.bias],
                f"bias_sd_{unit}": [b / conv for b in self.bias_sd],
                f"shift_{unit}": [b / conv for b in self.shift],
                f"bound_{unit}": [b / conv for b in self.bound],
                "bound_source": self.bound_source}


def _windows(N: int, w: int) -> list[slice]:
    return [slice(k, k + w) for k in range(0, N - w + 1, w)]


def find_rest(t: np.ndarray, rates: np.ndarray, accel: np.ndarray | None, H: np.ndarray,
              sample_rate_hz: float) -> RestStretch | None:
    """The rest stretch before take-off (module docstring, step 1), or None.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times (s).
    rates : ndarray, shape (N, n)
        Calibrated gyro outputs ``SF·u − b`` (rad/s; NaN where missing).
    accel : ndarray, shape (N, k, 3), or None
        Each IMU's specific force (m/s²).
    H : ndarray, shape (n, 3)
        Calibrated gyro axes.
    sample_rate_hz : float
    """
    t = np.asarray(t, float)
    y = np.asarray(rates, float)
    N = y.shape[0]
    w = max(round(REST_WINDOW_S * sample_rate_hz), 5)
    if N < 2 * w:
        return None
    sls = _windows(N, w)
    still, moving = _still_windows(y, accel, sls, np.linalg.pinv(np.asarray(H, float)), w)
    first_move = int(np.argmax(moving)) if moving.any() else len(sls)
    best = _longest_run(still[:first_move])
    if (best[1] - best[0]) * w / sample_rate_hz < MIN_REST_S - 1e-9:
        return None
    i0, i1 = sls[best[0]].start, sls[best[1] - 1].stop
    return RestStretch(t0_s=float(t[i0]), t1_s=float(t[i1 - 1]), samples=int(i1 - i0),
                       takeoff_s=float(t[sls[first_move].start]) if first_move < len(sls)
                       else None,
                       judged_on="gyros and accelerometers" if accel is not None else "gyros")


def _still_windows(y: np.ndarray, accel: np.ndarray | None, sls: list[slice],
                   pinv: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Which windows are still and which show motion (module docstring, step 1).

    Parameters
    ----------
    y : ndarray, shape (N, n)
        Calibrated gyro outputs (rad/s).
    accel : ndarray, shape (N, k, 3), or None
    sls : list of slice
        The windows.
    pinv : ndarray, shape (3, n)
        Pseudo-inverse of the gyro axes.
    w : int
        Window length (samples).

    Returns
    -------
    still, moving : ndarray of bool, shape (len(sls),)
    """
    still = np.zeros(len(sls), bool)
    moving = np.zeros(len(sls), bool)
    prev_m = prev_a = None
    for j, sl in enumerate(sls):
        m, quiet, moving[j] = _gyro_window(y[sl], pinv, prev_m, w)
        if accel is not None:
            prev_a, quiet, moving[j] = _accel_window(np.asarray(accel[sl], float), prev_a,
                                                     quiet, moving[j])
        prev_m = m
        still[j] = quiet and not moving[j]
    return still, moving


def _gyro_window(yw: np.ndarray, pinv: np.ndarray, prev_m: np.ndarray | None, w: int
                 ) -> tuple[np.ndarray | None, bool, bool]:
    """The gyros' verdict on one window.

    Parameters
    ----------
    yw : ndarray, shape (w, n)
    pinv : ndarray, shape (3, n)
    prev_m : ndarray or None
        The previous window's mean (None when it was not finite).
    w : int

    Returns
    -------
    m : ndarray or None
        The window's mean; None when a value is not finite.
    quiet : bool
        Slow, low-noise and no step from the previous window.
    moving : bool
        Fast or noisy.
    """
    if not np.all(np.isfinite(yw)):
        return None, False, False
    m = yw.mean(axis=0)
    s = yw.std(axis=0, ddof=1)
    rate = float(np.linalg.norm(pinv @ m))
    moving = rate > MOTION_RATE_DPS * DPS or bool(np.any(s > MOTION_GYRO_SD_DPS * DPS))
    quiet = rate < REST_RATE_DPS * DPS and bool(np.all(s <= REST_GYRO_SD_DPS * DPS))
    if quiet and prev_m is not None:
        step = np.maximum(4.0 * s * math.sqrt(2.0 / w), REST_GYRO_STEP_DPS * DPS)
        quiet = bool(np.all(np.abs(m - prev_m) <= step))
    return m, quiet, moving


def _accel_window(aw: np.ndarray, prev_a: np.ndarray | None, quiet: bool, moving: bool
                  ) -> tuple[np.ndarray | None, bool, bool]:
    """The accelerometers' verdict on one window, added to the gyros'.

    Parameters
    ----------
    aw : ndarray, shape (w, k, 3)
    prev_a : ndarray or None
        The previous window's mean specific force (None when it was not finite).
    quiet, moving : bool
        The gyros' verdict.

    Returns
    -------
    am : ndarray, shape (k, 3), or None
        The window's mean; None when a value is not finite.
    quiet, moving : bool
    """
    if not np.all(np.isfinite(aw)):
        return None, False, moving
    am = aw.mean(axis=0)                                  # (k, 3)
    dev = np.abs(np.linalg.norm(am, axis=1) - G0)
    asd = aw.std(axis=0, ddof=1)
    moving = moving or bool(np.any(asd > MOTION_ACCEL_SD))
    quiet = (quiet and bool(np.all(dev <= REST_G_TOLERANCE))
             and bool(np.all(asd <= REST_ACCEL_SD)))
    if quiet and prev_a is not None:
        quiet = bool(np.all(np.linalg.norm(am - prev_a, axis=1) < REST_ACCEL_STEP))
    return am, quiet, moving


def _longest_run(still: np.ndarray) -> tuple[int, int]:
    """The first longest run of True, as (start, stop) indices; (0, 0) when none.

    Parameters
    ----------
    still : ndarray of bool

    Returns
    -------
    (int, int)
    """
    best, run, start = (0, 0), 0, 0
    for j in range(len(still)):
        if still[j]:
            if run == 0:
                start = j
            run += 1
            if run > best[1] - best[0]:
                best = (start, start + run)
        else:
            run = 0
    return best


def estimate_rest_bias(flight: Any, cal: Calibration, stretch: RestStretch, kind: str = "gyro"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Biases (SI) and their sd from a rest stretch (module docstring, step 2)."""
    s = cal.kind(kind)
    t = np.asarray(flight.t, float)
    keep = (t >= stretch.t0_s - 1e-9) & (t <= stretch.t1_s + 1e-9)
    u = np.asarray(flight.raw, float)[keep] * s.scale_factors
    N = u.shape[0]
    b = u.mean(axis=0)
    w = max(round(REST_WINDOW_S * cal.sample_rate_hz), 5)
    white = u.std(axis=0, ddof=1) / math.sqrt(N)
    nw = N // w
    if nw >= 2:
        means = u[: nw * w].reshape(nw, w, -1).mean(axis=1)
        scatter = means.std(axis=0, ddof=1) / math.sqrt(nw)
    else:
        scatter = white
    return b, np.maximum(white, scatter)


def _turn_on_sd(cal: Calibration, kind: str) -> np.ndarray | None:
    """The calibration's per-sensor ``bias_turn_on_sd`` (SI), None unless every sensor has it."""
    v = [getattr(c, "bias_turn_on_sd", None) for c in cal.kind(kind).sensors]
    if any(x is None or not math.isfinite(float(x)) for x in v):
        return None
    return np.asarray(v, float)


def _bound(cal: Calibration, kind: str, bias_bound_dps: float | None
           ) -> tuple[np.ndarray, str]:
    n = cal.kind(kind).n
    conv = DPS if kind == "gyro" else 1.0
    if bias_bound_dps is not None:
        b = float(bias_bound_dps)
        if not (math.isfinite(b) and b >= 0):
            raise ConfigError(f"--bias-bound-dps must be >= 0 and finite, got {b}")
        return np.full(n, b * conv), f"--bias-bound-dps {b:g}"
    sd = _turn_on_sd(cal, kind)
    if sd is not None:
        return BOUND_SIGMAS * sd, (f"{BOUND_SIGMAS:g} x the calibration's bias_turn_on_sd "
                                   f"(run-to-run spread)")
    return (np.full(n, DEFAULT_BIAS_BOUND_DPS * conv),
            f"default {DEFAULT_BIAS_BOUND_DPS:g} deg/s: the calibration states no "
            f"bias_turn_on_sd; give --bias-bound-dps")


def same_power_up(cal: Calibration, flight: Any) -> bool | None:
    """True on the calibration's own power-up, False on another, None when the calibration
    records no flight.

    Its own power-up is its flight (the same fingerprint), the same recording read again
    (same sample count, first and last times within 1 ms) or a part of the same log: the
    same source (the whole path the calibration was made from, not only the file name:
    every Xsens DOT path of the shared data is ``IMU_1.csv`` … ``IMU_4.csv``, and
    autopilots number their logs from 1 on every card) with times inside the calibrated
    flight's. A calibration of several flights together is the power-up of none of them
    (its bias is their mean): False. A flight whose log names another firmware than the
    calibration's (:mod:`replay.firmware`) is another power-up: False.
    """
    from replay.time_offsets import flight_identity

    inflight = cal.extras.inflight
    known = inflight.flight if inflight is not None else None
    if known is None or not known.fingerprint:
        return None
    alignment = cal.extras.inflight_alignment
    if alignment is not None and len(alignment.flights) > 1:
        return False
    here = flight_identity(flight)
    if here["fingerprint"] == known.fingerprint:
        return True
    if known.firmware and here["firmware"] and here["firmware"] != known.firmware:
        return False                # another firmware build: another power-up (replay.firmware)
    if _read_again(here, known):
        return True                 # the same recording read again (another format, float32)
    return _part_of_log(here, known, flight.source, cal.extras.source)


def _read_again(here: dict[str, Any], known: Any) -> bool:
    """The same recording read again: the same sample count, first and last times within
    1 ms of the calibrated flight's.

    Parameters
    ----------
    here : dict
        :func:`replay.time_offsets.flight_identity` of the flight.
    known : FlightIdentity
        The calibrated flight's (``extra.inflight.flight``).

    Returns
    -------
    bool
    """
    return (here["samples"] == known.samples and known.t0_s is not None
            and known.t1_s is not None and abs(here["t0_s"] - known.t0_s) < 1e-3
            and abs(here["t1_s"] - known.t1_s) < 1e-3)


def _part_of_log(here: dict[str, Any], known: Any, source: Any, whole: Any) -> bool:
    """A part of the calibrated log: the same source file, the same whole path, and times
    inside the calibrated flight's.

    Parameters
    ----------
    here : dict
        :func:`replay.time_offsets.flight_identity` of the flight.
    known : FlightIdentity
    source : str or Path
        The flight's source.
    whole : str or None
        The path the calibration was made from (``extra.source``).

    Returns
    -------
    bool
    """
    if not known.source or here["source"] != known.source or not here["samples"]:
        return False
    if not whole or str(source) != str(whole):
        return False                # only the file name agrees: another log of that name
    t0, t1 = known.t0_s, known.t1_s
    return (t0 is not None and t1 is not None and here["t0_s"] >= t0 - 1e-6
            and here["t1_s"] <= t1 + 1e-6)


def turn_on_for_flight(flight: Any, cal: Calibration, *, kind: str = "gyro",
                       mode: str = "auto", bias_bound_dps: float | None = None) -> TurnOn:
    """What to do about the turn-on bias on ``flight`` (module docstring).

    Parameters
    ----------
    flight : replay.flight_data.Flight
    cal : Calibration
    kind : str
        Only gyros have a rest estimate (an accelerometer's bias is not seen at rest
        without knowing the attitude); accelerometer sets get the bound or nothing.
    mode : str
        One of :data:`MODES`.
    bias_bound_dps : float, optional
        ``--bias-bound-dps``: the nominal bound per sensor (°/s for gyros, m/s² for
        accelerometers), over the calibration's spread and the default.

    Raises
    ------
    ConfigError
        An unknown mode or a bad bound.
    """
    if mode not in MODES:
        raise ConfigError(f"--turn-on must be one of {', '.join(MODES)}, got {mode!r}")
    s = cal.kind(kind)
    b0 = s.biases
    sd0 = np.array([c.bias_sd for c in s.sensors], float)
    zero = tuple(0.0 for _ in range(s.n))

    def calibrated(why: str) -> TurnOn:
        return TurnOn("calibrated", why, None, tuple(b0), tuple(sd0), zero, kind=kind)

    if mode == "off":
        return calibrated("--turn-on off")
    own = same_power_up(cal, flight)
    if mode == "auto":
        if own:
            return calibrated("the calibration's own flight (same power-up)")
        if own is None and _turn_on_sd(cal, kind) is None and bias_bound_dps is None:
            return calibrated("a calibration that records no flight and states no "
                              "run-to-run bias spread; --turn-on rest or bound to change")
    stretch = None
    if mode in ("auto", "rest") and kind == "gyro":
        stretch = find_rest(flight.t, _rates(flight, cal, kind), _accel(flight), s.H,
                            float(flight.sample_rate_hz))
    if stretch is not None:
        b, sd = estimate_rest_bias(flight, cal, stretch, kind)
        return TurnOn("rest", "estimated at rest before take-off", stretch, tuple(b),
                      tuple(sd), tuple(b - b0), kind=kind)
    if mode == "auto" and _turn_on_sd(cal, kind) is None and bias_bound_dps is None:
        # no measured spread and none given: a guessed bound would blind the monitor to
        # faults of its size (2 deg/s steps went unseen under the 1 deg/s default), so auto
        # keeps the calibrated biases and says how to cover the spread
        return calibrated("no rest stretch before take-off and no measured run-to-run "
                          "bias spread: biases as calibrated (calibrate several flights "
                          "together, or --bias-bound-dps / --turn-on bound)")
    bound, src = _bound(cal, kind, bias_bound_dps)
    why = ("--turn-on bound" if mode == "bound" else
           "no rest stretch before take-off in this log" if kind == "gyro" else
           "accelerometer biases are not estimated at rest")
    return TurnOn("bound", why, None, tuple(b0), tuple(sd0), zero, tuple(bound), src, kind)


def _rates(flight: Any, cal: Calibration, kind: str) -> np.ndarray:
    s = cal.kind(kind)
    raw = np.asarray(flight.raw, float)
    return np.where(np.asarray(flight.valid, bool), raw * s.scale_factors - s.biases, np.nan)


def _accel(flight: Any) -> np.ndarray | None:
    from replay.envelope import flight_accel

    return flight_accel(flight)


def apply_turn_on(cal: Calibration, turn_on: TurnOn) -> Calibration:
    """The calibration with the biases and bias sd the monitor uses (``rest``); unchanged
    otherwise (the bound enters the thresholds, :mod:`fdi.bias_bound`)."""
    if turn_on.method != "rest":
        return cal
    s = cal.kind(turn_on.kind)
    sens = tuple(replace(c, bias=float(b), bias_sd=float(sd))
                 for c, b, sd in zip(s.sensors, turn_on.bias, turn_on.bias_sd, strict=True))
    return replace(cal, sets={**cal.sets, turn_on.kind: replace(s, sensors=sens)})
