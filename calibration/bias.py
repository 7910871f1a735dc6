"""Gyro biases with the Earth rate removed, two ways.

With the gains ``a = h̃/SF`` of the rate test (:mod:`calibration.rate_test`) the offset
``c = b/SF`` of each sensor follows from means over chosen samples. Both estimators are
linear in segment means, so they come as operators (rows over segments) and their
covariance with the gains is exact under white noise.

``"model"`` (default)
    Explicit model: latitude and table attitude are known, so the Earth rate in the body
    frame ``ω_ie_b(t)`` is computed at every sample and removed with the table rate::

        c = mean_k(ū_k − a·(x̄_table,k + x̄_earth,k))      over every step (rate and position)

    (seed 001 Eq. 17 is the special case of position steps only, seed 000 Eq. 20 with the
    Earth rate in the input.)

``"turns"`` (seed 000 Eq. 20)
    Average over whole turns of the outer (vertical) axis: the horizontal Earth rate
    ``Ω cos φ`` turns with the table and its mean over a whole number of turns is zero, so it
    needs no model. Only the samples of the outer-axis steps inside the largest whole number
    of turns from the step start are used. What does *not* average out is the vertical
    component ``Ω sin φ`` along the outer axis: it is constant in the body frame during an
    outer-axis step (``Ω sin φ·up_b``) and would stay in the bias (seed 000 assumes the
    sequence cancels it; its Table 1 rows with inner angles 0/180°, ±90°, ±30° do so only
    partly). rimu subtracts it with the known latitude and the table's Up vector in the
    body frame: the "turns" estimate is therefore model-free for the horizontal Earth rate
    and uses the latitude for the vertical one. The size of that correction is reported
    (``vertical_correction``) so a user can see what seed 000's plain average would have
    left in the bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["OUTER_STEP_RATE_MIN", "TurnWindows", "is_outer_step", "offset_operator", "turn_windows"]

OUTER_STEP_RATE_MIN = 1e-4
"""Smallest outer-axis rate (rad/s) for a step to count as an outer-axis rate step."""


@dataclass(frozen=True)
class TurnWindows:
    """Whole-turn windows of the outer-axis steps.

    Attributes
    ----------
    in_window : ndarray of bool, shape (N,)
        Sample lies in the whole-turn window of its step.
    steps : tuple of int
        Steps (1-based) that contribute at least one whole turn.
    turns : tuple of int
        Whole turns used per step.
    short_steps : tuple of int
        Outer-axis steps shorter than one turn (not used).
    """

    in_window: np.ndarray
    steps: tuple[int, ...]
    turns: tuple[int, ...]
    short_steps: tuple[int, ...]


def is_outer_step(inner_rate: np.ndarray, outer_rate: np.ndarray) -> bool:
    """A rate step about the outer axis only (inner axis still)."""
    return bool(np.median(np.abs(outer_rate)) > OUTER_STEP_RATE_MIN
                and np.max(np.abs(inner_rate)) <= OUTER_STEP_RATE_MIN)


def turn_windows(step: np.ndarray, outer: np.ndarray, inner_rate: np.ndarray,
                 outer_rate: np.ndarray, step_numbers: list[int]) -> TurnWindows:
    """Samples inside the largest whole number of outer-axis turns of each outer step.

    Parameters
    ----------
    step : ndarray of int, shape (N,)
        1-based step per sample (samples of a step in time order).
    outer : ndarray, shape (N,)
        Outer angle (rad).
    inner_rate, outer_rate : ndarray, shape (N,)
        Table rates (rad/s).
    step_numbers : list of int
        Steps to consider.
    """
    inw = np.zeros(step.shape, bool)
    used, turns, short = [], [], []
    for k in step_numbers:
        idx = np.flatnonzero(step == k)
        if idx.size < 2 or not is_outer_step(inner_rate[idx], outer_rate[idx]):
            continue
        ang = np.unwrap(outer[idx])
        trav = np.abs(ang - ang[0])
        d = float(np.median(np.abs(np.diff(ang))))
        if d <= 0:
            continue
        total = trav[-1] + d                         # each sample stands for one interval
        m = int(np.floor(total / (2 * np.pi) + 1e-6))
        if m < 1:
            short.append(int(k))
            continue
        inw[idx[trav < m * 2 * np.pi - 0.5 * d]] = True
        used.append(int(k))
        turns.append(m)
    return TurnWindows(inw, tuple(used), tuple(turns), tuple(short))


def offset_operator(weights: np.ndarray, seg_mean_x: np.ndarray,
                    op_a: np.ndarray) -> np.ndarray:
    """Row operator of ``c = Σ_s w_s·(ū_s − a·x̄_s)`` over segments.

    Parameters
    ----------
    weights : ndarray, shape (S,)
        Segment weights summing to 1 (samples per segment over the total used; 0 for
        segments not used).
    seg_mean_x : ndarray, shape (S, 3)
        Mean input removed in each segment (table rate plus the Earth rate as modelled).
    op_a : ndarray, shape (3, S)
        Gain operator, ``a = op_a @ ū``.

    Returns
    -------
    ndarray, shape (S,)
        ``c = op @ ū``.
    """
    w = np.asarray(weights, float)
    xbar = np.nan_to_num(np.asarray(seg_mean_x, float)).T @ w        # (3,)
    return w - xbar @ op_a
