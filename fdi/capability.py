"""What a healthy set can tell apart, per sensor pair and per body axis.

Isolation is a statistical decision (:func:`fdi.isolation.decide`): two sensors whose whitened
parity columns are nearly parallel cannot be told apart at the noise the set has, even when
their axes differ by a degree. For the model of one healthy set
(:class:`fdi.reconstruction.SetModel`) this module lays out, at rest and for the longest
window:

- per pair (i, j): sin θ_ij between the whitened columns and the bias on i from which the
  hypothesis of j is rejected with probability 1 − P_md at the stated risk of wrong
  exclusion (``isolable_from``, SI: rad/s for gyros);
- per sensor: the bias detected with probability 1 − P_md;
- per body axis: the sensors whose faults move that axis (those it reconstructs from,
  share ≥ 10 % of their largest), and the bias from which every pair of them is told apart
  (inf: a fault there is detected, never attributed).

All sizes are SI; :func:`capability_report` converts them with the factor it is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["AXES", "AXIS_SHARE", "PairCapability", "capability_report", "moved_axes"]

AXES = ("x", "y", "z")
"""Body axes of the reconstructed rate."""
AXIS_SHARE = 0.1
"""A sensor moves a body axis when its reconstruction column moves that axis by at least
this share of the axis it moves most."""


def moved_axes(g: np.ndarray) -> np.ndarray:
    """Body axes a sensor's reconstruction column ``g`` (3,) moves (:data:`AXIS_SHARE`);
    every axis when the column is not finite or zero (nothing can be ruled out)."""
    g = np.abs(np.asarray(g, float))
    if not (np.all(np.isfinite(g)) and g.max() > 0):
        return np.ones(3, bool)
    return g >= AXIS_SHARE * g.max()


@dataclass(frozen=True)
class PairCapability:
    """One pair of healthy sensors (1-based) and how well the set tells them apart."""

    i: int
    j: int
    sin_theta: float
    isolable_from: float

    def to_dict(self, scale: float = 1.0) -> dict[str, Any]:
        """JSON-ready; sizes multiplied by ``scale`` (a unit conversion)."""
        f = self.isolable_from * scale
        return {"sensors": [self.i, self.j], "sin_theta": self.sin_theta,
                "isolable_from": f if np.isfinite(f) else None}


def capability_report(model: Any, names: tuple[str, ...] | list[str], scale: float = 1.0,
                      unit: str = "SI") -> dict[str, Any]:
    """Capability of one set per pair and per body axis, JSON-ready.

    Parameters
    ----------
    model : fdi.reconstruction.SetModel
    names : sequence of str
        Sensor names (all n sensors, in order).
    scale : float
        Factor applied to every size (e.g. 1/DPS for °/s).
    unit : str
        Name of the unit after scaling.

    Returns
    -------
    dict
        ``capability``, ``unit``, ``detectable`` per sensor, ``pairs`` (worst first), and
        ``axes``: per body axis the sensors that move it and ``isolable_from``.
    """
    idx = list(model.idx)
    m = len(idx)
    iso = np.asarray(model.isolable_from, float)
    sin = np.asarray(model.sines, float)
    pairs = []
    for a in range(m):
        for b in range(a + 1, m):
            worst = float(max(iso[a, b], iso[b, a])) if iso.size else float("inf")
            pairs.append(PairCapability(idx[a] + 1, idx[b] + 1,
                                        float(sin[a, b]) if sin.size else 0.0, worst))
    pairs.sort(key=lambda p: -p.isolable_from if np.isfinite(p.isolable_from) else -np.inf)
    axes = []
    G = np.asarray(model.G, float)
    for k, ax in enumerate(AXES):
        movers = []
        for c, i in enumerate(idx):
            g = np.abs(G[:, i])
            if np.all(np.isfinite(g)) and g.max() > 0 and moved_axes(g)[k]:
                movers.append(c)
        worst = 0.0
        for a in movers:
            for b in movers:
                if a != b:
                    worst = max(worst, float(iso[a, b]))
        f = worst * scale
        axes.append({"axis": ax, "sensors": [names[idx[c]] for c in movers],
                     "isolable_from": f if np.isfinite(f) else None})
    det = np.asarray(model.detectable, float) * scale
    return {"capability": model.capability, "unit": unit,
            "detectable": {names[i]: (float(d) if np.isfinite(d) else None)
                           for i, d in zip(idx, det, strict=True)},
            "pairs": [p.to_dict(scale) | {"names": [names[p.i - 1], names[p.j - 1]]}
                      for p in pairs],
            "axes": axes}
