"""Body-rate profiles of a manoeuvring vehicle, deterministic functions of time and seed.

Time is cut into segments of :data:`SEGMENT_S` seconds. In every segment each body axis
makes one smooth rate pulse ``A·sin²(π(t − t₀)/w)`` (zero rate and zero angular
acceleration at both ends, so the profile is C¹ everywhere), of width ``w`` between 0.4 s
and the segment length, at a random position in the segment. The amplitude ``A`` is
±``max_rate`` with probability :data:`FULL_SCALE_P` (a full-scale manoeuvre) and otherwise
uniform in ``[−max_rate, max_rate]``. With 2-s segments and three axes that gives on
average 18 full-scale manoeuvres per minute, and every rate stays within ±``max_rate``.

The parameters of a block of :data:`BLOCK_SEGMENTS` segments are drawn from
``default_rng([seed, 3, block])``, so any time range can be evaluated on its own (chunked
simulation of long flights) and gives the same rates as the whole flight would.
"""

from __future__ import annotations

import numpy as np

from fdi.units import DPS

__all__ = ["BLOCK_SEGMENTS", "FULL_SCALE_P", "SEGMENT_S", "body_rates"]

SEGMENT_S = 2.0
"""Length of one manoeuvre segment (s)."""
BLOCK_SEGMENTS = 256
"""Segments whose parameters are drawn together from one seeded generator."""
FULL_SCALE_P = 0.2
"""Probability that a pulse reaches the full ±max rate."""
_MIN_WIDTH_S = 0.4


def _block_params(seed: int, block: int, max_rate: float) -> np.ndarray:
    """Pulse parameters of one block: shape (BLOCK_SEGMENTS, 3 axes, 3 = amp, start, width)."""
    rng = np.random.default_rng([int(seed), 3, int(block)])
    shape = (BLOCK_SEGMENTS, 3)
    full = rng.random(shape) < FULL_SCALE_P
    sign = np.where(rng.random(shape) < 0.5, -1.0, 1.0)
    amp = np.where(full, sign * max_rate, rng.uniform(-max_rate, max_rate, shape))
    width = rng.uniform(_MIN_WIDTH_S, SEGMENT_S, shape)
    start = rng.random(shape) * (SEGMENT_S - width)
    return np.stack([amp, start, width], axis=-1)


def body_rates(t: np.ndarray, *, seed: int, max_rate_dps: float = 300.0) -> np.ndarray:
    """Body rates at times ``t``.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Times (s, ≥ 0).
    seed : int
        Same seed and time, same rate.
    max_rate_dps : float
        Largest rate on each axis (°/s).

    Returns
    -------
    ndarray, shape (N, 3)
        Body rates (rad/s, MB frame).
    """
    t = np.asarray(t, dtype=float)
    out = np.zeros((t.shape[0], 3))
    if t.shape[0] == 0 or max_rate_dps <= 0:
        return out
    max_rate = float(max_rate_dps) * DPS
    seg = np.floor(np.maximum(t, 0.0) / SEGMENT_S).astype(np.int64)
    block = seg // BLOCK_SEGMENTS
    b0, b1 = int(block.min()), int(block.max())
    params = np.concatenate([_block_params(seed, b, max_rate) for b in range(b0, b1 + 1)])
    idx = seg - b0 * BLOCK_SEGMENTS
    p = params[idx]                                   # (N, 3, 3)
    tau = (np.maximum(t, 0.0) - seg * SEGMENT_S)[:, None] - p[..., 1]
    w = p[..., 2]
    inside = (tau >= 0.0) & (tau <= w)
    out[:] = np.where(inside, p[..., 0] * np.sin(np.pi * np.clip(tau, 0.0, None) / w) ** 2,
                      0.0)
    return out
