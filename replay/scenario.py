"""Fault scenarios: faults injected into a healthy recording, so it carries known truth.

A scenario file (``rimu.scenario/1`` TOML) lists faults in the terms of
:mod:`replay.faults` (kinds step, ramp, stuck, noise, scale, spike, dropout; sizes as in
``--fault``: ``15sigma``, ``0.02dps``, ``0.05sigma/s``, ``3x``, ``1%``)::

    schema = "rimu.scenario/1"
    seed = 0                      # for the 'noise' kind

    [[faults]]
    sensor = 3
    kind = "step"
    size = "15sigma"
    onset = 20.0                  # s, flight time (0 = the log's first frame)
    duration = 5.0                # optional; default: to the end

    [[faults]]
    spec = "ramp:2:0.05sigma/s:10"   # or the --fault text itself

The faults are applied to the recorded **raw** samples through the calibration (the true
scale factors of a real sensor are unknown; the calibrated ones are the best estimate), with
the same time windows as :func:`replay.flight.simulate_flight`:

========  ==========================================================================
step      ``u_i += size / SF_i``  (spike: the one sample at onset, or the window)
ramp      ``u_i += size·(t − onset) / SF_i``
scale     ``u_i += size·(SF_i·u_i − b_i) / SF_i`` (the compensated output grows by size)
noise     ``u_i += sqrt(size² − 1)·σ_i·N(0,1) / SF_i`` (white noise multiplied by size ≥ 1)
stuck     ``u_i`` holds its last valid value before onset
dropout   no sample (``valid = False``, raw NaN)
========  ==========================================================================
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from fdi.fileio import Fields
from replay.faults import Fault, parse_fault

__all__ = ["SCENARIO_SCHEMA", "add_fault_signal", "apply_faults", "inject", "load_scenario"]

SCENARIO_SCHEMA = "rimu.scenario/1"


def load_scenario(path: str | Path, cal: Calibration, *,
                  kind: str = "gyro") -> tuple[tuple[Fault, ...], int]:
    """Read a scenario file: (faults, seed).

    Raises
    ------
    FileFormatError
        Naming the file, the line and the field (``faults[2].size``); unknown keys too.
    """
    r = Fields.from_toml(path, SCENARIO_SCHEMA)
    seed = r.integer("seed", 0)
    n = cal.kind(kind).n
    faults = tuple(_fault(e, cal, kind, n) for e in r.tables("faults"))
    r.finish()
    return faults, seed


def _fault(e: Fields, cal: Calibration, kind: str, n: int) -> Fault:
    """One ``[[faults]]`` table: ``spec = "KIND:SENSOR:SIZE:ONSET[:DURATION]"`` or its parts."""
    spec = e.string("spec", None)
    if spec is None:
        parts = [e.get("kind"), e.get("sensor"), e.get("size", ""), e.get("onset")]
        dur = e.get("duration", None)
        spec = ":".join(str(v) for v in parts + ([] if dur is None else [dur]))
    e.finish()
    try:
        f = parse_fault(spec, cal, kind=kind)
    except ConfigError as exc:
        raise e.error(None, str(exc)) from None
    if not 1 <= f.sensor <= n:
        raise e.error("sensor", f"sensor {f.sensor} out of range 1..{n}")
    if f.kind == "noise" and f.size < 1.0:
        raise e.error("size", "a recording's noise can only be multiplied by ≥ 1")
    return f


def apply_faults(t: np.ndarray, raw: np.ndarray, valid: np.ndarray,
                 faults: Sequence[Fault], cal: Calibration, *, kind: str = "gyro",
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Inject faults into recorded raw samples (see the module docstring).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times (s).
    raw : ndarray, shape (N, n)
        Raw outputs.
    valid : ndarray of bool, shape (N, n)
    faults : sequence of Fault
    cal : Calibration
    kind : str
    seed : int
        Seed of the extra noise (``noise`` kind).

    Returns
    -------
    raw, valid : ndarray
        New arrays (the inputs are not modified).
    """
    s = cal.kind(kind)
    sf = s.scale_factors
    b = s.biases
    sd = s.noise_sd
    t = np.asarray(t, float)
    raw = np.array(raw, dtype=float, copy=True)
    valid = np.array(valid, dtype=bool, copy=True)
    rng = np.random.default_rng([int(seed), 11])
    n = raw.shape[1]
    for f in faults:
        i = f.sensor - 1
        if not 0 <= i < n:
            raise ConfigError(f"fault {f.spec or f.kind}: sensor {f.sensor} out of range 1..{n}")
        if f.kind == "spike" and f.duration is None:
            # the one sample at onset: the first at or after it (simulate_flight's k_on)
            m = np.zeros(t.shape, bool)
            after = np.flatnonzero(t >= f.onset - 1e-9)
            if after.size:
                m[after[0]] = True
        else:
            m = (t >= f.onset - 1e-12) & (t < f.end - 1e-12)
        if not m.any():
            continue
        if f.kind == "stuck":
            before = np.flatnonzero(~m & (t < f.onset) & valid[:, i])
            if before.size:
                held = raw[before[-1], i]
            else:
                first = np.flatnonzero(m & valid[:, i])
                held = raw[first[0], i] if first.size else np.nan
            raw[m, i] = held
        elif f.kind == "dropout":
            valid[m, i] = False
        else:
            add_fault_signal(raw, m, f, t, sf, b, sd, rng)
    raw[~valid] = np.nan
    return raw, valid


def add_fault_signal(raw: np.ndarray, m: np.ndarray, f: Fault, t: np.ndarray,
                     sf: np.ndarray, b: np.ndarray, sd: np.ndarray,
                     rng: np.random.Generator) -> None:
    """Add an additive fault (step, spike, ramp, scale, noise) to ``raw[m, f.sensor - 1]``.

    ``raw`` (raw units, shape (N, n)) is changed in place; ``sf``, ``b``, ``sd`` are the
    calibration's scale factors, biases and noise sd (SI). Stuck and dropout are not
    additive: the callers handle them (a whole flight and a stream hold values differently).
    One arithmetic for the whole-flight :func:`apply_faults` and the streamed
    :class:`replay.stream.ChunkInjector`.
    """
    i = f.sensor - 1
    if f.kind in ("step", "spike"):
        raw[m, i] += f.size / sf[i]
    elif f.kind == "ramp":
        raw[m, i] += f.size * (t[m] - f.onset) / sf[i]
    elif f.kind == "scale":
        raw[m, i] += f.size * (sf[i] * raw[m, i] - b[i]) / sf[i]
    elif f.kind == "noise":
        # s*s, not s**2: a huge factor gives inf (marked by the monitor), not OverflowError
        extra = math.sqrt(max(f.size * f.size - 1.0, 0.0)) * sd[i] / sf[i]
        raw[m, i] += extra * rng.standard_normal(int(m.sum()))


def inject(flight: Any, faults: Sequence[Fault], cal: Calibration, *,
           seed: int = 0, source: str = "") -> Any:
    """A copy of ``flight`` with ``faults`` applied to its raw samples and added to its truth.

    The truth record gains ``"injected": {"faults": [...], "seed", "source"}``.
    """
    raw, valid = apply_faults(flight.t, flight.raw, flight.valid, faults, cal,
                              kind=flight.kind, seed=seed)
    truth: dict[str, Any] = dict(flight.truth)
    truth["injected"] = {"faults": [f.to_dict() for f in faults], "seed": int(seed),
                         "source": source}
    return replace(flight, raw=raw, valid=valid, faults=tuple(flight.faults) + tuple(faults),
                   truth=truth)
