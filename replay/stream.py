"""Fault injection into a replay that streams a log piece by piece.

:class:`ChunkInjector` applies a scenario's faults (:mod:`replay.scenario`) to successive
pieces of decoded samples with the result :func:`replay.scenario.apply_faults` gives on
the whole flight: a ``stuck`` fault holds the last valid value seen before its onset in any
earlier piece, a ``spike`` hits the first sample at or after its onset once. The extra noise
of ``noise`` faults is drawn from one generator seeded as ``apply_faults`` does, piece after
piece, so the draws equal the whole-flight ones when a single ``noise`` fault is active at
a time (with overlapping ``noise`` faults the draws are interleaved differently: same
distribution, other numbers).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from fdi.calfile import Calibration
from fdi.errors import ConfigError
from replay.faults import Fault
from replay.scenario import add_fault_signal

__all__ = ["ChunkInjector", "scenario_injector"]


class ChunkInjector:
    """Inject faults into successive pieces of a flight (see the module docstring).

    Parameters
    ----------
    faults : sequence of Fault
    cal : Calibration
    kind : str
    seed : int
        Seed of the extra noise.
    n : int
        Sensors in the flight (checked against the faults).

    Raises
    ------
    ConfigError
        A fault names a sensor out of range.
    """

    def __init__(self, faults: Sequence[Fault], cal: Calibration, *, kind: str = "gyro",
                 seed: int = 0, n: int | None = None) -> None:
        s = cal.kind(kind)
        n = s.n if n is None else n
        for f in faults:
            if not 1 <= f.sensor <= n:
                raise ConfigError(f"fault {f.spec or f.kind}: sensor {f.sensor} out of range "
                                  f"1..{n}")
        self.faults = list(faults)
        self.sf, self.b, self.sd = s.scale_factors, s.biases, s.noise_sd
        self.rng = np.random.default_rng([int(seed), 11])
        self._held: dict[int, float] = {}
        self._spiked: set[int] = set()

    def apply(self, piece: Any) -> Any:
        """The piece (a :class:`~replay.flight.Flight`) with the faults applied."""
        t = np.asarray(piece.t, float)
        raw = np.array(piece.raw, dtype=float, copy=True)
        valid = np.array(piece.valid, dtype=bool, copy=True)
        sf, b, sd = self.sf, self.b, self.sd
        for j, f in enumerate(self.faults):
            i = f.sensor - 1
            if f.kind == "spike" and f.duration is None:
                m = np.zeros(t.shape, bool)
                if j not in self._spiked:
                    after = np.flatnonzero(t >= f.onset - 1e-9)
                    if after.size:
                        m[after[0]] = True
                        self._spiked.add(j)
            else:
                m = (t >= f.onset - 1e-12) & (t < f.end - 1e-12)
            if f.kind == "stuck":
                before = np.flatnonzero(~m & (t < f.onset) & valid[:, i])
                if before.size:
                    self._held[j] = float(raw[before[-1], i])
            if not m.any():
                continue
            if f.kind == "stuck":
                if j not in self._held:
                    first = np.flatnonzero(m & valid[:, i])
                    self._held[j] = float(raw[first[0], i]) if first.size else math.nan
                raw[m, i] = self._held[j]
            elif f.kind == "dropout":
                valid[m, i] = False
            else:
                add_fault_signal(raw, m, f, t, sf, b, sd, self.rng)
        raw[~valid] = np.nan
        return replace(piece, raw=raw, valid=valid)


def scenario_injector(path: Any, cal: Calibration, header: Any, *, kind: str = "gyro",
                      n: int | None = None) -> tuple[ChunkInjector, Any]:
    """A scenario file's injector and the log's header with its faults and truth added
    (``rimu replay --inject``)."""
    from replay.scenario import load_scenario

    faults, seed = load_scenario(path, cal, kind=kind)
    injector = ChunkInjector(faults, cal, kind=kind, seed=seed, n=n)
    truth = dict(header.truth)
    truth["injected"] = {"faults": [f.to_dict() for f in faults], "seed": int(seed),
                         "source": str(path)}
    return injector, replace(header, faults=tuple(header.faults) + tuple(faults), truth=truth)
