"""Flights: sample sets of a redundant sensor set in flight, simulated or recorded.

Simulation
----------
:func:`simulate_flight` (and :func:`iter_flight` for long flights, chunk by chunk) makes
the body rates of a manoeuvring vehicle (:mod:`replay.motion`, up to ``max_rate_dps`` on
each axis) and passes them through a *true* sensor model that differs from the
calibration the way real sensors do (seed 000 Eq. 13, seed 001 Eq. 1)::

    raw_i = (h_i·ω + b_i + f_i(t)) / SF_i + η_i / SF_i,   η ~ N(0, Σ)

- with a truth calibration (a calibration session's truth sidecar) its axes ``h_i``, scale
  factors ``SF_i`` and biases ``b_i`` are used as they are;
- otherwise they are drawn from the calibration file's own uncertainty: the gain-normalised
  axis ``h_i/SF_i`` errs by ``δ_i ~ N(0, input_error_cov_i)`` (in units of the calibrated
  gain), and ``b_i ~ N(b̂_i, bias_sd_i²)``, so calibration error is present in every flight;
- ``Σ`` is the calibration's per-sample noise covariance (the truth's when it has one),
  scaled by ``fs/fs_cal`` when the flight's sample rate differs (white noise of the same
  density);
- the truth's extra *effects* (``calibration.effects``: g-sensitivity, ...) are not
  simulated in flight; their names are listed in the truth record
  (``"effects_not_simulated"``);
- optionally an in-run bias drift (first-order Gauss-Markov and/or random walk,
  ``bias_instability``/``random_walk``; streams ``default_rng([seed, 4, c])``), off by default;
- ``f_i(t)`` are the injected faults (:mod:`replay.faults`); ``stuck`` replaces the raw
  output, ``dropout`` clears ``valid`` (raw NaN).

The gyros sense ω, the total inertial rate of the body (Earth rate is not added separately).
Random streams are keyed on the seed and the absolute sample index, so a flight is the same
however it is chunked: true parameters from ``default_rng([seed, 1])``, the noise of
internal chunk c (:data:`CHUNK_SAMPLES` samples) from ``default_rng([seed, 2, c])``, the
motion as in :mod:`replay.motion`.

Flight directory ``rimu.flight/1``
----------------------------------
``DIR/manifest.json``::

    {"schema": "rimu.flight/1", "sample_rate_hz": 100.0, "kind": "gyro",
     "sensor_names": ["g1", ...], "raw_unit": "mV", "columns": ["t", "g1", ...],
     "samples": N, "samples_file": "samples.csv", "source": "..."}

``DIR/samples.csv``: one header line (the columns), then one line per sample: ``t`` (s) and
the raw output of each sensor in its raw unit; an **empty cell means no sample** from that
sensor (``valid = False``), while ``nan``/``inf`` are values the sensor sent.

``DIR/truth.json`` (optional; only simulated or fault-injected flights have one)::

    {"schema": "rimu.flight-truth/1", "faults": [Fault.to_dict(), ...],
     "true_parameters": {"axis": n×3, "scale_factor": [SI input per raw unit],
                         "bias": [SI], "noise_covariance": n×n SI², "source": ...},
     "rates_file": "truth_rates.npy", "seed": ..., ...}

``DIR/truth_rates.npy``: the true body rates, float64, shape (N, 3), rad/s.
:func:`write_truth_sidecar` / :func:`read_truth_sidecar` read and write the truth beside any
file (CAN logs use them too).
"""

from __future__ import annotations

import io
import json
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError, FileFormatError
from fdi.fileio import Fields, read_json_object, to_jsonable
from replay.faults import Fault, fault_from_dict
from replay.motion import body_rates

__all__ = [
    "CHUNK_SAMPLES",
    "FLIGHT_SCHEMA",
    "FLIGHT_TRUTH_SCHEMA",
    "Flight",
    "TrueModel",
    "concat_flights",
    "draw_true_model",
    "iter_flight",
    "load_flight_dir",
    "read_truth_sidecar",
    "save_flight_dir",
    "simulate_flight",
    "true_model_from_calibration",
    "write_truth_sidecar",
]

FLIGHT_SCHEMA = "rimu.flight/1"
FLIGHT_TRUTH_SCHEMA = "rimu.flight-truth/1"
CHUNK_SAMPLES = 65536
"""Samples per internal simulation chunk (the noise stream is keyed on the chunk index)."""


@dataclass(frozen=True, eq=False)
class Flight:
    """Samples of one sensor set in flight.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times (s).
    raw : ndarray, shape (N, n)
        Raw outputs (sensor units); NaN where ``valid`` is False.
    valid : ndarray of bool, shape (N, n)
        False where a sensor sent no sample.
    sample_rate_hz : float
    sensor_names : tuple of str
    raw_unit : str
    omega_true : ndarray, shape (N, 3) or None
        True body rates (rad/s), when known.
    faults : tuple of Fault
        Injected faults, when known.
    truth : dict
        The JSON-able truth record (``rimu.flight-truth/1`` without the rates), or empty.
    source : str
        Where the flight came from (path or ``"<simulated>"``).
    kind : str
        ``"gyro"`` or ``"accel"``.
    """

    t: np.ndarray
    raw: np.ndarray
    valid: np.ndarray
    sample_rate_hz: float
    sensor_names: tuple[str, ...]
    raw_unit: str = "raw"
    omega_true: np.ndarray | None = None
    faults: tuple[Fault, ...] = ()
    truth: dict[str, Any] = field(default_factory=dict)
    source: str = "<memory>"
    kind: str = "gyro"

    @property
    def n(self) -> int:
        """Number of sensors."""
        return self.raw.shape[1]

    @property
    def duration_s(self) -> float:
        """Time span covered (s): N / sample rate."""
        return self.t.shape[0] / self.sample_rate_hz if self.sample_rate_hz > 0 else 0.0


@dataclass(frozen=True, eq=False)
class TrueModel:
    """The true sensor model a flight is simulated through.

    Attributes
    ----------
    axis : ndarray, shape (n, 3)
        True unit input axes.
    scale_factor : ndarray, shape (n,)
        True SF (SI input per raw unit).
    bias : ndarray, shape (n,)
        True bias (SI).
    noise_covariance : ndarray, shape (n, n)
        Per-sample noise covariance of the true input (SI²).
    source : str
        ``"truth"`` or ``"drawn from calibration covariance"``.
    """

    axis: np.ndarray
    scale_factor: np.ndarray
    bias: np.ndarray
    noise_covariance: np.ndarray
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (SI)."""
        return {"axis": self.axis.tolist(), "scale_factor": self.scale_factor.tolist(),
                "bias": self.bias.tolist(), "noise_covariance": self.noise_covariance.tolist(),
                "units": {"scale_factor": "SI input per raw unit", "bias": "SI input",
                          "noise_covariance": "SI input^2 per sample"},
                "source": self.source}


def draw_true_model(cal: Calibration, seed: int, *, kind: str = "gyro") -> TrueModel:
    """True parameters drawn from the calibration's own uncertainty.

    ``h_i/SF_i = (ĥ_i + δ_i)/ŜF_i`` with ``δ_i ~ N(0, input_error_cov_i)`` (the
    gain-normalised error of the file's ``input_error_cov``), ``b_i ~ N(b̂_i, bias_sd_i²)``.
    """
    s = cal.kind(kind)
    rng = np.random.default_rng([int(seed), 1])
    axes, sfs, bs = [], [], []
    for c in s.sensors:
        C = np.asarray(c.input_error_cov, float)
        delta = _sqrtm(C) @ rng.standard_normal(3)
        a = np.asarray(c.axis, float) + delta            # gain-normalised true axis
        g = float(np.linalg.norm(a))
        axes.append(a / g)
        sfs.append(c.scale_factor / g)                   # h·x/SF_true = a·x/SF_cal
        bs.append(c.bias + c.bias_sd * rng.standard_normal())
    return TrueModel(np.array(axes), np.array(sfs), np.array(bs),
                     np.array(s.noise_covariance, float), "drawn from calibration covariance")


def true_model_from_calibration(truth: Calibration | Sequence[Any], cal: Calibration, *,
                                kind: str = "gyro") -> TrueModel:
    """True parameters from a truth calibration (or the tuple ``load_truth`` returns).

    The noise covariance is the truth's when it is non-zero, else the calibration's.
    """
    tc = truth if isinstance(truth, Calibration) else truth[0]
    if not isinstance(tc, Calibration):
        raise ConfigError("truth must be a Calibration or (Calibration, effects, ...)")
    ts, cs = tc.kind(kind), cal.kind(kind)
    if ts.n != cs.n:
        raise ConfigError(f"truth has {ts.n} {kind} sensors, the calibration {cs.n}")
    noise = np.array(ts.noise_covariance, float)
    if noise.shape != (cs.n, cs.n) or not np.any(noise):
        noise = np.array(cs.noise_covariance, float)
    return TrueModel(ts.H.copy(), ts.scale_factors.copy(), ts.biases.copy(), noise, "truth")


def _sqrtm(C: np.ndarray) -> np.ndarray:
    """A square root L (L·Lᵀ = C) of a symmetric positive semi-definite matrix."""
    C = 0.5 * (np.asarray(C, float) + np.asarray(C, float).T)
    w, V = np.linalg.eigh(C)
    return V * np.sqrt(np.clip(w, 0.0, None))


def _check_faults(faults: Sequence[Fault], n: int) -> tuple[Fault, ...]:
    out = tuple(faults)
    for f in out:
        if not isinstance(f, Fault):
            raise ConfigError(f"faults must be replay.faults.Fault, got {type(f).__name__}")
        if not 1 <= f.sensor <= n:
            raise ConfigError(f"fault {f.spec or f.kind}: sensor {f.sensor} out of range 1..{n}")
    return out


def iter_flight(cal: Calibration, duration_s: float, *, seed: int,
                faults: Sequence[Fault] = (), truth: Calibration | Sequence[Any] | None = None,
                sample_rate_hz: float | None = None, max_rate_dps: float = 300.0,
                kind: str = "gyro", bias_instability: float | Sequence[float] = 0.0,
                bias_correlation_s: float = 100.0,
                random_walk: float | Sequence[float] = 0.0) -> Iterator[Flight]:
    """Simulate a flight in chunks of :data:`CHUNK_SAMPLES` samples.

    Same arguments as :func:`simulate_flight`; yields consecutive :class:`Flight` pieces
    whose concatenation equals ``simulate_flight(...)``. Memory stays bounded for flights
    of many hours.
    """
    s = cal.kind(kind)
    n = s.n
    fs = float(sample_rate_hz or cal.sample_rate_hz)
    if not (math.isfinite(fs) and fs > 0):
        raise ConfigError(f"sample rate must be positive, got {fs}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ConfigError(f"duration must be positive, got {duration_s}")
    faults = _check_faults(faults, n)
    gm_sd = _per_sensor(bias_instability, n, "bias_instability")
    rw_q = _per_sensor(random_walk, n, "random_walk")
    if gm_sd.any() and not (math.isfinite(bias_correlation_s) and bias_correlation_s > 0):
        raise ConfigError(f"bias_correlation_s must be positive, got {bias_correlation_s}")
    drift = bool(gm_sd.any() or rw_q.any())
    phi = math.exp(-1.0 / (fs * bias_correlation_s)) if gm_sd.any() else 0.0
    model = (true_model_from_calibration(truth, cal, kind=kind) if truth is not None
             else draw_true_model(cal, seed, kind=kind))
    if cal.sample_rate_hz > 0 and fs != cal.sample_rate_hz:
        # white noise of a fixed density: per-sample variance grows with the sample rate
        model = replace(model, noise_covariance=model.noise_covariance * (fs /
                                                                          cal.sample_rate_hz))
    L = _sqrtm(model.noise_covariance)
    N = round(duration_s * fs)
    names = tuple(c.name for c in s.sensors)
    raw_unit = s.sensors[0].raw_unit if n else "raw"
    truth_doc = _truth_doc(cal, model, faults, seed=seed, fs=fs, N=N,
                           max_rate_dps=max_rate_dps, kind=kind)
    if truth is not None and not isinstance(truth, Calibration) and len(truth) > 1 \
            and truth[1]:
        truth_doc["effects_not_simulated"] = sorted(str(k) for k in truth[1])
    k_on = {id(f): math.ceil(f.onset * fs - 1e-9) for f in faults}
    if drift:
        truth_doc["bias_drift"] = {"bias_instability": gm_sd.tolist(),
                                   "bias_correlation_s": float(bias_correlation_s),
                                   "random_walk": rw_q.tolist(),
                                   "units": "SI input; random walk per sqrt(s)"}
    held: dict[int, float] = {}
    last_raw = np.full(n, np.nan)
    gm_state = gm_sd * np.random.default_rng([int(seed), 5]).standard_normal(n)  # stationary
    rw_state = np.zeros(n)
    for c, k0 in enumerate(range(0, N, CHUNK_SAMPLES)):
        k1 = min(N, k0 + CHUNK_SAMPLES)
        k = np.arange(k0, k1)
        t = k / fs
        omega = body_rates(t, seed=seed, max_rate_dps=max_rate_dps)
        x = omega @ model.axis.T                                   # (m, n) true input
        rng = np.random.default_rng([int(seed), 2, c])
        eta = rng.standard_normal((k.shape[0], n)) @ L.T
        valid = np.ones((k.shape[0], n), bool)
        add = np.zeros_like(x)
        for f in faults:
            i = f.sensor - 1
            ko = k_on[id(f)]
            if f.kind == "spike" and f.duration is None:
                m = k == ko
            else:
                m = (t >= f.onset - 1e-12) & (t < f.end - 1e-12)
            if not m.any():
                continue
            if f.kind == "step" or f.kind == "spike":
                add[m, i] += f.size
            elif f.kind == "ramp":
                add[m, i] += f.size * (t[m] - f.onset)
            elif f.kind == "scale":
                add[m, i] += f.size * x[m, i]
            elif f.kind == "noise":
                eta[m, i] *= f.size
        if drift:
            d, gm_state, rw_state = _bias_drift(np.random.default_rng([int(seed), 4, c]),
                                                k.shape[0], gm_sd, phi, gm_state, rw_q, fs,
                                                rw_state)
            add += d
        raw = (x + model.bias + add + eta) / model.scale_factor
        for f in faults:
            i = f.sensor - 1
            if f.kind == "stuck":
                m = (t >= f.onset - 1e-12) & (t < f.end - 1e-12)
                if not m.any():
                    continue
                if id(f) not in held:
                    ko = k_on[id(f)]
                    if ko == 0:
                        held[id(f)] = float(raw[0, i])
                    elif ko - 1 >= k0:
                        held[id(f)] = float(raw[ko - 1 - k0, i])
                    else:
                        held[id(f)] = float(last_raw[i])
                raw[m, i] = held[id(f)]
        for f in faults:
            if f.kind == "dropout":
                m = (t >= f.onset - 1e-12) & (t < f.end - 1e-12)
                valid[m, f.sensor - 1] = False
        raw[~valid] = np.nan
        last_raw = raw[-1].copy()
        yield Flight(t=t, raw=raw, valid=valid, sample_rate_hz=fs, sensor_names=names,
                     raw_unit=raw_unit, omega_true=omega, faults=faults, truth=truth_doc,
                     source="<simulated>", kind=kind)


def _per_sensor(v: float | Sequence[float], n: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(v, float), (n,)).copy() if np.ndim(v) == 0 \
        else np.asarray(v, float)
    if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ConfigError(f"{name} must be one non-negative number or {n}, got {v!r}")
    return a


def _bias_drift(rng: np.random.Generator, m: int, gm_sd: np.ndarray, phi: float,
                gm_state: np.ndarray, rw_q: np.ndarray, fs: float, rw_state: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Markov bias + bias random walk of one chunk, shape (m, n), and the new states.

    ``b[k] = φ·b[k−1] + √(1−φ²)·σ·w`` (φ = exp(−dt/τ), stationary sd σ) and
    ``r[k] = r[k−1] + q·√dt·w'``.
    """
    from scipy.signal import lfilter

    n = gm_sd.shape[0]
    w = rng.standard_normal((m, 2 * n))
    out = np.zeros((m, n))
    if gm_sd.any():
        g = math.sqrt(1.0 - phi * phi)
        gm, _ = lfilter([1.0], [1.0, -phi], w[:, :n] * (g * gm_sd), axis=0,
                        zi=(phi * gm_state)[None, :])
        out += gm
        gm_state = gm[-1].copy()
    if rw_q.any():
        rw = rw_state + np.cumsum(w[:, n:] * (rw_q / math.sqrt(fs)), axis=0)
        out += rw
        rw_state = rw[-1].copy()
    return out, gm_state, rw_state


def _truth_doc(cal: Calibration, model: TrueModel, faults: Sequence[Fault], *, seed: int,
               fs: float, N: int, max_rate_dps: float, kind: str) -> dict[str, Any]:
    s = cal.kind(kind)
    return {"schema": FLIGHT_TRUTH_SCHEMA, "seed": int(seed), "kind": kind,
            "configuration": cal.configuration, "sample_rate_hz": fs, "samples": N,
            "max_rate_dps": float(max_rate_dps),
            "motion": "replay.motion: sin^2 rate pulses per 2-s segment and axis",
            "sigma": s.noise_sd.tolist(),
            "faults": [f.to_dict() for f in faults],
            "true_parameters": model.to_dict()}


def concat_flights(pieces: Sequence[Flight]) -> Flight:
    """Join consecutive flight pieces (same sensors) into one flight."""
    if not pieces:
        raise ConfigError("no flight pieces to join")
    first = pieces[0]
    has_truth = all(p.omega_true is not None for p in pieces)
    return replace(first,
                   t=np.concatenate([p.t for p in pieces]),
                   raw=np.concatenate([p.raw for p in pieces]),
                   valid=np.concatenate([p.valid for p in pieces]),
                   omega_true=(np.concatenate([p.omega_true for p in pieces])
                               if has_truth else None))


def simulate_flight(cal: Calibration, duration_s: float, *, seed: int,
                    faults: Sequence[Fault] = (),
                    truth: Calibration | Sequence[Any] | None = None,
                    sample_rate_hz: float | None = None, max_rate_dps: float = 300.0,
                    kind: str = "gyro", bias_instability: float | Sequence[float] = 0.0,
                    bias_correlation_s: float = 100.0,
                    random_walk: float | Sequence[float] = 0.0) -> Flight:
    """Simulate a manoeuvring flight with calibration error and injected faults.

    Parameters
    ----------
    cal : Calibration
        The calibration the monitor will use.
    duration_s : float
        Flight length (s); ``round(duration_s·fs)`` samples at ``t = k/fs``.
    seed : int
    faults : sequence of Fault
    truth : Calibration or tuple, optional
        True sensor parameters (a session's truth sidecar, ``calibration.truth.load_truth``);
        drawn from the calibration's covariance when None.
    sample_rate_hz : float, optional
        Defaults to the calibration's rate.
    max_rate_dps : float
        Largest body rate on each axis (°/s).
    kind : str
    bias_instability : float or sequence of float
        Stationary sd of a first-order Gauss-Markov bias per sensor (SI input units);
        0 (default): none. In-run bias drift that the calibration does not know.
    bias_correlation_s : float
        Its correlation time (s).
    random_walk : float or sequence of float
        Bias random walk density per sensor (SI per √s); 0: none.

    Returns
    -------
    Flight
        With ``omega_true``, ``faults`` and ``truth`` filled in.
    """
    return concat_flights(list(iter_flight(cal, duration_s, seed=seed, faults=faults,
                                           truth=truth, sample_rate_hz=sample_rate_hz,
                                           max_rate_dps=max_rate_dps, kind=kind,
                                           bias_instability=bias_instability,
                                           bias_correlation_s=bias_correlation_s,
                                           random_walk=random_walk)))


# -- files -------------------------------------------------------------------------------
def _fmt_column(v: np.ndarray, ok: np.ndarray) -> np.ndarray:
    s = np.char.mod("%.17g", v).astype(object)
    s[~ok] = ""
    return s


def save_flight_dir(flight: Flight, directory: str | Path) -> None:
    """Write a flight as ``DIR/manifest.json``, ``DIR/samples.csv`` and the truth sidecar.

    The truth (``truth.json`` + ``truth_rates.npy``) is written when the flight has faults,
    true rates or a truth record.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    n = flight.n
    manifest = {"schema": FLIGHT_SCHEMA, "sample_rate_hz": float(flight.sample_rate_hz),
                "kind": flight.kind, "sensor_names": list(flight.sensor_names),
                "raw_unit": flight.raw_unit, "columns": ["t", *flight.sensor_names],
                "samples": int(flight.t.shape[0]), "samples_file": "samples.csv",
                "source": flight.source}
    cols = [_fmt_column(flight.t, np.ones_like(flight.t, bool))]
    cols += [_fmt_column(flight.raw[:, i], flight.valid[:, i]) for i in range(n)]
    with open(d / "samples.csv", "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(manifest["columns"]) + "\n")
        step = 100_000
        for a in range(0, flight.t.shape[0], step):
            rows = [",".join(r) for r in zip(*(c[a:a + step] for c in cols), strict=True)]
            fh.write("\n".join(rows) + "\n")
    (d / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
    if flight.faults or flight.omega_true is not None or flight.truth:
        write_truth_sidecar(flight, d / "truth.json")
    else:
        for name in ("truth.json", "truth_rates.npy"):
            (d / name).unlink(missing_ok=True)


def write_truth_sidecar(flight: Flight, path: str | Path) -> None:
    """Write the flight's truth as ``rimu.flight-truth/1`` JSON at ``path``.

    The true rates go to ``<stem>_rates.npy`` beside it (``truth_rates.npy`` for
    ``truth.json``), named in the JSON's ``"rates_file"``.
    """
    p = Path(path)
    doc = dict(flight.truth)
    doc["schema"] = FLIGHT_TRUTH_SCHEMA
    doc["faults"] = [f.to_dict() for f in flight.faults]
    doc["samples"] = int(flight.t.shape[0])
    doc["sample_rate_hz"] = float(flight.sample_rate_hz)
    if flight.omega_true is not None:
        rates = p.with_name(p.stem + "_rates.npy")
        np.save(rates, np.asarray(flight.omega_true, float))
        doc["rates_file"] = rates.name
        doc["rates_unit"] = "rad/s"
    else:
        doc.pop("rates_file", None)
    p.write_text(json.dumps(to_jsonable(doc), indent=1) + "\n", encoding="utf-8")


def read_truth_sidecar(path: str | Path, *, samples: int | None = None
                       ) -> tuple[tuple[Fault, ...], dict[str, Any], np.ndarray | None]:
    """Read a ``rimu.flight-truth/1`` file: (faults, truth record, true rates or None).

    Raises
    ------
    FileFormatError
        Naming the file and the field (or the rates file and its shape).
    """
    p = Path(path)
    doc = read_json_object(p, FLIGHT_TRUTH_SCHEMA)
    raw_faults = doc.get("faults", [])
    if not isinstance(raw_faults, list):
        raise FileFormatError(str(p), "expected a list", field="faults")
    faults = []
    for j, fd in enumerate(raw_faults):
        if not isinstance(fd, Mapping):
            raise FileFormatError(str(p), "expected an object", field=f"faults[{j}]")
        try:
            faults.append(fault_from_dict(fd, f"faults[{j}]"))
        except ConfigError as exc:
            raise FileFormatError(str(p), str(exc), field=f"faults[{j}]") from None
    rates = None
    rf = doc.get("rates_file")
    if rf is not None:
        if not isinstance(rf, str) or not rf or Path(rf).name != rf:
            raise FileFormatError(str(p), f"expected a file name beside it, got {rf!r}",
                                  field="rates_file")
        rp = p.with_name(rf)
        try:
            rates = np.load(rp, allow_pickle=False)
        except Exception as exc:        # a damaged .npy header fails in many ways (EOFError,
            # ValueError, SyntaxError, tokenize.TokenError from its literal header, ...)
            why = exc.strerror if isinstance(exc, OSError) else f"{type(exc).__name__}: {exc}"
            raise FileFormatError(str(rp), f"cannot read the true rates {p.name} names "
                                  f"({why})",
                                  field="rates_file") from None
        if rates.dtype.kind not in "fiu":
            raise FileFormatError(str(rp), f"expected numbers, got dtype {rates.dtype}",
                                  field="rates_file")
        if rates.ndim != 2 or rates.shape[1] != 3 or (samples is not None
                                                       and rates.shape[0] != samples):
            want = f"({samples}, 3)" if samples is not None else "(N, 3)"
            raise FileFormatError(str(rp), f"expected shape {want}, got {rates.shape}")
        rates = rates.astype(float)
    doc.pop("rates_file", None)
    return tuple(faults), doc, rates


_EMPTY_CELL = re.compile(rb"(?<=,)(?=,|\n)|^(?=,)", re.MULTILINE)


def _load_samples(path: Path, ncol: int, columns: Sequence[str]) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    """Numbers and missing-mask of a samples.csv: ((N, ncol) float, (N, ncol) bool)."""
    p = str(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FileFormatError(p, f"cannot read ({exc.strerror})") from None
    data = data.replace(b"\r\n", b"\n")
    nl = data.find(b"\n")
    header = (data if nl < 0 else data[:nl]).decode("utf-8", "replace").strip()
    got = [h.strip() for h in header.split(",")]
    if got != list(columns):
        raise FileFormatError(p, f"header {got} does not match the manifest's columns "
                                 f"{list(columns)}", line=1)
    body = b"" if nl < 0 else data[nl + 1:]
    body = body.rstrip(b"\n")
    if body:
        body += b"\n"
    if not body:
        return np.zeros((0, ncol)), np.zeros((0, ncol), bool)
    b = np.frombuffer(body, np.uint8)
    nl_pos = np.flatnonzero(b == 10)
    delim = np.flatnonzero((b == 44) | (b == 10))
    # cells per line: delimiters up to and including each newline
    per_line = np.diff(np.concatenate([[0], np.searchsorted(delim, nl_pos, side="right")]))
    bad = np.flatnonzero(per_line != ncol)
    if bad.size:
        j = int(bad[0])
        raise FileFormatError(p, f"{per_line[j]} cells, expected {ncol}", line=j + 2)
    starts = np.concatenate([[0], delim[:-1] + 1])
    missing = (delim == starts).reshape(-1, ncol)
    if missing[:, 0].any():
        j = int(np.flatnonzero(missing[:, 0])[0])
        raise FileFormatError(p, "empty time", line=j + 2, field=columns[0])
    filled = _EMPTY_CELL.sub(b"nan", body) if missing.any() else body
    try:
        vals = np.loadtxt(io.BytesIO(filled), delimiter=",", dtype=float, ndmin=2)
    except ValueError:
        _locate_bad_cell(p, body.decode("utf-8", "replace"), columns)
        raise FileFormatError(p, "cannot parse") from None
    return vals.reshape(-1, ncol), missing


def _locate_bad_cell(p: str, text: str, columns: Sequence[str]) -> None:
    for j, line in enumerate(text.split("\n")):
        for c, cell in enumerate(line.split(",")):
            if cell.strip() == "" and c > 0:
                continue
            try:
                float(cell)
            except ValueError:
                raise FileFormatError(p, f"{cell!r} is not a number", line=j + 2,
                                      field=columns[c] if c < len(columns) else None) from None


def load_flight_dir(directory: str | Path) -> Flight:
    """Read a flight directory written by :func:`save_flight_dir` (or by hand).

    Raises
    ------
    FileFormatError
        Naming the file, line and column (or field) of the first problem.
    """
    d = Path(directory)
    mpath = d / "manifest.json"
    m = Fields.from_json(mpath, FLIGHT_SCHEMA)
    fs = m.number("sample_rate_hz", positive=True)
    names = m.get("sensor_names")
    if not isinstance(names, list) or not names or not all(isinstance(x, str) for x in names):
        raise m.error("sensor_names", "expected a non-empty list of strings")
    columns = m.get("columns", ["t", *names])
    if columns != ["t", *names]:
        raise m.error("columns", f"expected ['t', *sensor_names], got {columns!r}")
    kind = m.choice("kind", ("gyro", "accel"), "gyro")
    raw_unit = m.string("raw_unit", "raw")
    n_samples = m.get("samples", None)
    spath = d / m.string("samples_file", "samples.csv")
    m.string("source", "", nonempty=False)
    m.finish()
    sp = str(spath)
    if not spath.is_file():
        raise FileFormatError(sp, f"cannot read (no such file); {mpath.name} names it",
                              field="samples_file")
    vals, missing = _load_samples(spath, len(columns), columns)
    if n_samples is not None and n_samples != vals.shape[0]:
        raise m.error("samples", f"says {n_samples!r} samples, {spath.name} has "
                      f"{vals.shape[0]} (truncated or edited?)")
    t = vals[:, 0].copy()
    raw = vals[:, 1:].copy()
    valid = ~missing[:, 1:]
    raw[~valid] = np.nan
    if t.size and not np.all(np.isfinite(t)):
        j = int(np.flatnonzero(~np.isfinite(t))[0])
        raise FileFormatError(sp, "non-finite time", line=j + 2,
                              field="t")
    if t.size > 1 and np.any(np.diff(t) < 0):
        j = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
        raise FileFormatError(sp, "time goes backwards", line=j + 2,
                              field="t")
    faults: tuple[Fault, ...] = ()
    truth: dict[str, Any] = {}
    rates = None
    if (d / "truth.json").exists():
        faults, truth, rates = read_truth_sidecar(d / "truth.json", samples=t.shape[0])
    return Flight(t=t, raw=raw, valid=valid, sample_rate_hz=float(fs),
                  sensor_names=tuple(names), raw_unit=raw_unit,
                  omega_true=rates, faults=faults, truth=truth, source=str(d), kind=kind)
