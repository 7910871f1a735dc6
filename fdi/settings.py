"""Settings of the monitor: detection thresholds (a file) and behaviour (persistence, health).

:class:`Thresholds` is what ``thresholds.compute_thresholds`` produces and
``rimu.thresholds/2`` files hold (``/1`` still loads); :class:`MonitorSettings` is the rest
of the monitor's behaviour (persistence, hysteresis, re-admission, health limits).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fdi.errors import ConfigError
from fdi.fileio import Fields, NumberRule, check_numbers, read_json_object

__all__ = [
    "DETECTORS",
    "NOISE_MODELS",
    "THRESHOLDS_NUMBER_RULES",
    "THRESHOLDS_SCHEMA",
    "THRESHOLDS_SCHEMAS",
    "MonitorSettings",
    "Thresholds",
    "load_thresholds",
    "thresholds_from_dict",
]

THRESHOLDS_SCHEMA = "rimu.thresholds/2"
THRESHOLDS_SCHEMAS = ("rimu.thresholds/1", THRESHOLDS_SCHEMA)
"""Versions the loader reads (``/1``: no calibration fingerprint, Gaussian white noise)."""
DETECTORS = ("windows", "cusum", "both")
NOISE_MODELS = ("gaussian-white", "gaussian-measured-variance", "overbound")
"""What the variance factors rest on: the Allan factors of a Gaussian residual; at one scale
at least the measured window-mean variance (significantly above Allan's); at one scale at
least the overbound of the calibration's residual tail model (:mod:`fdi.tails`)."""


@dataclass(frozen=True)
class Thresholds:
    """Detection thresholds for one sensor set.

    The monitor tests the whitened statistic of the running mean of the parity vector over
    windows of ``scales[k]`` samples::

        D_k = w/f_k · p̄ᵀ (VΣVᵀ)⁻¹ p̄      ~ χ²(m − 3) for healthy white noise

    against ``chi2.isf(alpha[k], m − 3)`` (m healthy sensors), times the inflation for the
    calibration uncertainty at the current rate.

    Attributes
    ----------
    kind : str
        ``"gyro"`` or ``"accel"``.
    n : int
        Number of sensors.
    sample_rate_hz : float
    false_alarms_per_hour : float
        The false-alarm budget these thresholds were made for.
    scales : tuple of int
        Window lengths in samples (1, 2, 4, ..., 2^K).
    alpha : tuple of float
        Per-sample false-alarm probability of each scale (Bonferroni split of the budget).
    variance_factor : tuple of float
        f_k ≥ 1: variance of the window mean relative to white noise (σ²/w), from the
        Allan variance of the calibration residuals at τ = w/fs, or the overbound of the
        residual's measured tail where that is larger and the residual is not Gaussian.
    threshold : tuple of float
        Threshold on D_k for the full set (m = n), for reference; the monitor recomputes it
        for each set of healthy sensors from ``alpha``.
    cusum_drift : float
        Allowance ν of the CUSUM on the whitened per-sensor projections (units of σ).
    cusum_threshold : float
        CUSUM decision threshold h for the full set (reference; recomputed per set).
    missed_detection : float
        Missed-detection probability of the protection level.
    detector : str
        ``"windows"`` (dyadic running means), ``"cusum"`` (the single-sample test plus a
        CUSUM bank) or ``"both"``.
    notes : str
        How the numbers were obtained.
    calibration_fingerprint : str
        :meth:`fdi.calfile.Calibration.fingerprint` of the calibration they were made from
        (empty: unknown, a ``/1`` file).
    noise_model : str
        One of :data:`NOISE_MODELS`.
    rate_error_factor : float
        q ≥ 1: the inflation for the calibration error at the current rate
        (``κ/f_w·Σ_w ρ``, :mod:`fdi.windows`) is taken q times, so the thresholds hold for
        a calibration error up to a stated quantile of the calibration's covariance, not
        only on average over errors (``rimu tune``: :func:`thresholds.per_draw.rate_error_factor`).
        Written to the file only when it is not 1.
    """

    kind: str
    n: int
    sample_rate_hz: float
    false_alarms_per_hour: float
    scales: tuple[int, ...]
    alpha: tuple[float, ...]
    variance_factor: tuple[float, ...]
    threshold: tuple[float, ...]
    cusum_drift: float = 0.5
    cusum_threshold: float = float("nan")
    missed_detection: float = 1e-3
    detector: str = "windows"
    notes: str = ""
    calibration_fingerprint: str = ""
    noise_model: str = "gaussian-white"
    rate_error_factor: float = 1.0
    schema: str = THRESHOLDS_SCHEMA

    def __post_init__(self) -> None:
        k = len(self.scales)
        if k == 0:
            raise ConfigError("thresholds: need at least one scale")
        for name in ("alpha", "variance_factor", "threshold"):
            if len(getattr(self, name)) != k:
                raise ConfigError(f"thresholds: {name} has {len(getattr(self, name))} "
                                  f"entries for {k} scales")
        if any(int(s) < 1 for s in self.scales):
            raise ConfigError("thresholds: scales must be positive window lengths")
        if any(not (0.0 < a < 1.0) for a in self.alpha):
            raise ConfigError("thresholds: alpha must lie in (0, 1)")
        if any(not (f > 0.0 and math.isfinite(f)) for f in self.variance_factor):
            raise ConfigError("thresholds: variance_factor must be positive and finite")
        if not (self.rate_error_factor >= 1.0 and math.isfinite(self.rate_error_factor)):
            raise ConfigError(f"thresholds: rate_error_factor must be >= 1 and finite, got "
                              f"{self.rate_error_factor}")
        if self.noise_model not in NOISE_MODELS:
            raise ConfigError(f"thresholds: noise_model must be one of {NOISE_MODELS}, "
                              f"got {self.noise_model!r}")
        if self.detector not in DETECTORS:
            raise ConfigError(f"thresholds: detector must be one of {DETECTORS}, "
                              f"got {self.detector!r}")
        if self.detector != "windows" and not (self.cusum_threshold > 0
                                               and self.cusum_drift > 0):
            raise ConfigError("thresholds: a CUSUM detector needs cusum_threshold > 0 "
                              "and cusum_drift > 0")

    @property
    def K(self) -> int:
        """Number of scales."""
        return len(self.scales)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary in the ``rimu.thresholds/2`` layout."""
        extra = ({} if self.rate_error_factor == 1.0
                 else {"rate_error_factor": self.rate_error_factor})
        return {"schema": THRESHOLDS_SCHEMA,
                "calibration_fingerprint": self.calibration_fingerprint,
                "noise_model": self.noise_model, "kind": self.kind, "n": self.n,
                "sample_rate_hz": self.sample_rate_hz,
                "false_alarms_per_hour": self.false_alarms_per_hour,
                "scales": list(self.scales), "alpha": list(self.alpha),
                "variance_factor": list(self.variance_factor),
                "threshold": list(self.threshold), "cusum_drift": self.cusum_drift,
                "cusum_threshold": (None if not math.isfinite(self.cusum_threshold)
                                    else self.cusum_threshold),
                "missed_detection": self.missed_detection, "detector": self.detector,
                "notes": self.notes, **extra}

    def save(self, path: str | Path) -> None:
        """Write as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")


def load_thresholds(path: str | Path) -> Thresholds:
    """Read and validate a ``rimu.thresholds/2`` (or ``/1``) file.

    Raises
    ------
    FileFormatError
        Missing file, bad JSON, wrong schema/version or a bad field (named in the message).
    """
    return thresholds_from_dict(read_json_object(path), str(path))


MAX_SCALE = 1 << 20
"""Longest window (samples) a thresholds file may ask for (2^20: about 3 h at 100 Hz)."""


THRESHOLDS_NUMBER_RULES: tuple[NumberRule, ...] = (
    NumberRule("threshold", 0.0, lo_open=True, what="a threshold on the statistic"),
    NumberRule("cusum_threshold", 0.0, lo_open=True, what="a CUSUM threshold"),
    NumberRule("cusum_drift", 0.0, lo_open=True, what="a CUSUM drift"),
    NumberRule("false_alarms_per_hour", 0.0, lo_open=True, what="a false-alarm rate"),
    NumberRule("variance_factor", 0.0, lo_open=True, what="a variance factor"),
    NumberRule("alpha", 0.0, 1.0, what="a probability"),
    NumberRule("missed_detection", 0.0, 1.0, what="a probability"),
    NumberRule("scales", 1.0, what="a window length"),
    NumberRule("n", 1.0, what="a sensor count"),
)
"""Ranges of the thresholds file's numbers (see :func:`fdi.fileio.check_numbers`); every
number must be finite."""


def thresholds_from_dict(doc: Any, path: str = "<thresholds>") -> Thresholds:
    """Build :class:`Thresholds` from its JSON dictionary (see :func:`load_thresholds`)."""
    r = Fields(doc, path)
    version = r.schema(THRESHOLDS_SCHEMAS)
    scales = r.numbers("scales")
    bad = [x for x in scales if x < 1 or x != int(x) or x > MAX_SCALE]
    if bad:         # the monitor keeps a ring of max(scales) sums: 1e308 would hang it
        raise r.error("scales", f"expected positive integers up to {MAX_SCALE}, got "
                      f"{bad[0]:g}")
    k = len(scales)
    fields = dict(
        kind=r.choice("kind", ("gyro", "accel")), n=r.integer("n", lo=1),
        detector=r.choice("detector", DETECTORS, "windows"),
        sample_rate_hz=r.number("sample_rate_hz", positive=True),
        false_alarms_per_hour=r.number("false_alarms_per_hour", positive=True),
        scales=tuple(int(s) for s in scales), alpha=_probabilities(r, "alpha", k),
        variance_factor=r.numbers("variance_factor", length=k, positive=True),
        threshold=r.numbers("threshold", length=k),
        cusum_drift=r.number("cusum_drift", 0.5, positive=True),
        cusum_threshold=r.number("cusum_threshold", float("nan")),
        missed_detection=_probabilities(r, "missed_detection", None),
        notes=r.string("notes", "", nonempty=False))
    if version != THRESHOLDS_SCHEMAS[0]:
        fp = r.string("calibration_fingerprint", "", nonempty=False)
        if fp and not (len(fp) == 16 and all(c in "0123456789abcdef" for c in fp)):
            raise r.error("calibration_fingerprint", f"expected 16 hex digits (from "
                          f"Calibration.fingerprint), got {fp!r}")
        fields["calibration_fingerprint"] = fp
        fields["noise_model"] = r.choice("noise_model", NOISE_MODELS)
        fields["rate_error_factor"] = r.number("rate_error_factor", 1.0, lo=1.0)
    r.finish()
    check_numbers(doc, path, THRESHOLDS_NUMBER_RULES)     # what the typed reads leave
    if fields["detector"] != "windows" and not fields["cusum_threshold"] > 0:
        raise r.error("cusum_threshold", f"a {fields['detector']!r} detector needs a positive "
                      "CUSUM threshold")
    try:
        return Thresholds(**fields)
    except ConfigError as exc:          # a combination __post_init__ refuses
        raise r.error(None, str(exc).removeprefix("thresholds: ")) from None


def _probabilities(r: Fields, key: str, k: int | None) -> Any:
    """``k`` probabilities in (0, 1) (k None: one, default 1e-3)."""
    p = r.numbers(key, length=k) if k is not None else (r.number(key, 1e-3),)
    if any(not 0 < a < 1 for a in p):
        raise r.error(key, "expected a probability in (0, 1)")
    return p if k is not None else p[0]


@dataclass(frozen=True)
class MonitorSettings:
    """Behaviour of :class:`fdi.monitor.Monitor` beyond the thresholds.

    Attributes
    ----------
    persistence : int
        Consecutive samples over threshold (counted from the detection) before a fault is
        confirmed and the sensor isolated.
    clear_ratio : float
        Hysteresis: a detection clears only when every statistic is below
        ``clear_ratio × threshold`` ...
    clear_samples : int
        ... for this many consecutive samples.
    clear_miss : float
        Floor of the clearing level: never so low that healthy white noise fails to clear
        in ``clear_samples`` samples with probability above this (union bound over the
        samples and the scales: the χ²(df) level exceeded with probability
        ``clear_miss / (clear_samples · scales)``), and never above the threshold. At the
        far-tail thresholds of low targets ``clear_ratio × threshold`` is above the floor
        and rules; at high targets (one alarm a minute) half the threshold lies in the
        bulk of the healthy statistic, a detection could never clear, and one episode
        would swallow every later alarm (:func:`fdi.detector.clear_thresholds`).
    readmission : bool
        Re-admit an isolated sensor after it behaved for ``readmit_dwell_s``. Off by
        default: isolated sensors stay isolated.
    readmit_dwell_s : float
        Minimum time (s) of good behaviour before re-admission.
    readmit_gate : float
        Re-admission gate on the squared standardised residual (dimensionless, in units of
        σ²): an isolated sensor behaves well at a sample only while
        (y_i − h_iᵀω̂)² < ``readmit_gate``·(Σ_ii + h_iᵀPh_i), its residual against the
        reconstruction of the healthy set over the residual's variance (its noise plus the
        reconstruction's, P = GΣGᵀ). 9 is a 3σ gate.
    stale_timeout_s : float
        A sensor without a valid sample for longer than this is isolated ("stale"). The
        clock runs on the good time stamps and, beside them, on the sample count: more
        than ``stale_timeout_s × sample_rate_hz`` samples in a row without a valid sample
        of the sensor is stale too, whatever the time stamps say (a frozen, non-finite or
        jumping time base never stops the clock).
    max_time_step_s : float
        A time stamp more than this after the last good one is implausible (``"jump"``):
        the monitor keeps testing the sample but does not take its time for its clocks.
        The same for one that is not finite (``"nonfinite"``) or earlier than the last
        good one (``"backward"``); each run of bad time stamps is one ``health`` event
        (sensor None, reason ``time nonfinite``, ``time backward`` or ``time jump``) and
        every answer carries its verdict (``Answer.time_status``).
    time_rebase_samples : int
        This many bad time stamps in a row that are consistent among themselves (finite,
        each within ``max_time_step_s`` after the one before) become the new time base
        (a clock reset or a genuine jump: ``health`` event ``time rebased``).
    noise_window_s : float
        Time constant (s) of the in-flight noise level v of the whitened parity: an
        exponential mean (gain λ = 1/(noise_window_s·fs)) of q_t = |z_t − z_{t−1}|²/(2·df),
        1 for healthy noise at the calibrated level. It reads differences, so a bias, a
        step (after its one onset sample) or a drift of any speed, whose differences are
        nothing, does not raise it: a slow fault cannot raise its own threshold.
    noise_clip : float
        Each q_t counts at most ``noise_clip``·v (one spike or a step's onset moves v by
        at most λ·(noise_clip − 1)·v).
    noise_band : float
        The thresholds (and the clearing levels) follow v only beyond 1 + ``noise_band``:
        scale s = min(K, max(1, v/(1 + noise_band))), so healthy noise at the calibrated
        level (and its colour at one sample's lag) leaves the tuned thresholds as they are.
    noise_scale_max : float
        K, the bound of s: the thresholds never rise beyond K times the calibrated ones
        (1: they never follow the flight's noise). A fault that makes noise can raise its
        own threshold by at most K; with a set that isolates, the vibration test below
        blames such a sensor.
    vibration_ratio : float
        The vibration test (sets that isolate): the same sensor has the largest noise level
        v_i along its unit whitened parity column, more than ``vibration_ratio`` times the
        next largest and above ``vibration_level`` (in units of the calibrated variance),
        and its in-flight variance in SI (Σ_ii plus the excess its level shows,
        :func:`fdi.kernel._in_flight_variance`) more than ``vibration_ratio`` times every
        other sensor's, for ``vibration_dwell_s``: it is excluded (status and event
        ``"vibration"``). The physical comparison keeps a sensor whose calibration
        understated its noise (a large v_i, a peer's noise in °/s) from being blamed.
        In expectation v_i is largest for the noisy sensor itself (the others see its
        noise through cos² of the angle between their columns), so the test never prefers
        a healthy sensor; a set whose columns are too close to reach the ratio never
        blames. 0 turns the test off.
    vibration_level : float
    vibration_dwell_s : float
    stuck_count : int
        This many identical consecutive raw values isolate a sensor ("stuck"; PX4: 100).
    raw_range : tuple of float or None
        (low, high) raw limits; a raw value at or beyond them isolates ("range").
    max_input : float or None
        |compensated value| (SI) at or above which a sensor is at its range limit; None
        takes 35 rad/s (2000 °/s) for gyros and 160 m/s² (16 g) for accelerometers.
    missed_detection : float or None
        Missed-detection probability for the protection level; None takes the thresholds'.
    wrong_exclusion : float
        Risk that one isolation decision excludes a healthy sensor while another one is
        faulty (:func:`fdi.isolation.decide`). Decisions are taken when a longer window lies
        wholly within the detection (at most one per window scale, then one per longest
        window), so the risk per fault episode is at most this times the number of scales
        plus one per longest window the episode lasts.
    isolation_ratio : float
        A set is reported able to isolate ("isolate") only when every pair of healthy
        sensors can be told apart from a bias at most this many times the largest
        detectable bias (:func:`fdi.reconstruction.isolation_sizes`); otherwise it detects,
        reports which sensors disagree and never excludes on the parity.
    """

    persistence: int = 3
    clear_ratio: float = 0.5
    clear_samples: int = 100
    clear_miss: float = 0.05
    readmission: bool = False
    readmit_dwell_s: float = 10.0
    readmit_gate: float = 9.0
    stale_timeout_s: float = 0.1
    max_time_step_s: float = 3600.0
    time_rebase_samples: int = 10
    noise_window_s: float = 2.0
    noise_clip: float = 9.0
    noise_band: float = 0.5
    noise_scale_max: float = 25.0
    vibration_ratio: float = 2.0
    vibration_level: float = 4.0
    vibration_dwell_s: float = 2.0
    stuck_count: int = 100
    raw_range: tuple[float, float] | None = None
    max_input: float | None = None
    missed_detection: float | None = None
    wrong_exclusion: float = 1e-7
    isolation_ratio: float = 10.0

    def __post_init__(self) -> None:
        # one check per group of settings, in the order they are documented; the first
        # setting out of its range is named
        self._check_decision()
        self._check_timing()
        self._check_noise()
        self._check_health()

    def _check_decision(self) -> None:
        if not 0.0 < self.wrong_exclusion < 0.5:
            raise ConfigError("wrong_exclusion must lie in (0, 0.5)")
        if not (self.isolation_ratio >= 1.0 and math.isfinite(self.isolation_ratio)):
            raise ConfigError("isolation_ratio must be finite and >= 1")
        if int(self.persistence) < 1:
            raise ConfigError("persistence must be >= 1 sample")
        if not 0.0 < self.clear_ratio <= 1.0:
            raise ConfigError("clear_ratio must lie in (0, 1]")
        if int(self.clear_samples) < 1:
            raise ConfigError("clear_samples must be >= 1")
        if not 0.0 < self.clear_miss < 1.0:
            raise ConfigError("clear_miss must lie in (0, 1)")

    def _check_timing(self) -> None:
        if not (self.stale_timeout_s > 0 and math.isfinite(self.stale_timeout_s)):
            raise ConfigError("stale_timeout_s must be positive and finite")
        if not (self.max_time_step_s > 0 and math.isfinite(self.max_time_step_s)):
            raise ConfigError("max_time_step_s must be positive and finite")
        if int(self.time_rebase_samples) < 2:
            raise ConfigError("time_rebase_samples must be >= 2")

    def _check_noise(self) -> None:
        for name in ("noise_window_s", "noise_clip", "noise_scale_max", "vibration_level",
                     "vibration_dwell_s"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ConfigError(f"{name} must be positive and finite")
        if not (self.noise_band >= 0 and math.isfinite(self.noise_band)):
            raise ConfigError("noise_band must be >= 0 and finite")
        if self.noise_clip < 1 or self.noise_scale_max < 1:
            raise ConfigError("noise_clip and noise_scale_max must be >= 1")
        if not (self.vibration_ratio == 0 or (self.vibration_ratio > 1
                                              and math.isfinite(self.vibration_ratio))):
            raise ConfigError("vibration_ratio must be 0 (off) or finite and > 1")

    def _check_health(self) -> None:
        if int(self.stuck_count) < 2:
            raise ConfigError("stuck_count must be >= 2")
        if self.readmit_dwell_s < 0:
            raise ConfigError("readmit_dwell_s must be >= 0")
        if not (self.readmit_gate > 0 and math.isfinite(self.readmit_gate)):
            raise ConfigError("readmit_gate must be positive and finite")
        if self.raw_range is not None and not self.raw_range[0] < self.raw_range[1]:
            raise ConfigError("raw_range must be (low, high) with low < high")
