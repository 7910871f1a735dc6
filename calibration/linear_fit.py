"""Stages 2 and 3 of the calibration: gyro gains (rate test) and offsets, as linear operators.

:func:`gyro_rate_test` runs the rate test over the paired ±ω steps
(:mod:`calibration.rate_test`, seed 000 Eqs. 16-19). :func:`fit_offsets` adds the offsets
``c = b/SF`` both ways (:mod:`calibration.bias`): the explicit model over every step and
seed 000's average over whole outer-axis turns (Eq. 20). Every estimate is a row operator
over the segment means (``θ = op @ ū_seg``), which is what makes the covariances of
:mod:`calibration.uncertainty` exact.

With extra regressors (:meth:`calibration.problem.GyroProblem.with_regressors`) the model
operator is the joint weighted least squares of ``u = a·x + c + β·z`` over the segments of
the bias steps; the rate test is still computed, as a check of the rate pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.bias import offset_operator
from calibration.problem import GyroProblem
from calibration.rate_test import RateTestFit, rate_test
from fdi.errors import CalibrationError

__all__ = ["MIN_STEP_SAMPLES", "LinearFit", "fail_steps", "fit_offsets", "gyro_rate_test"]

MIN_STEP_SAMPLES = 10
"""Fewest samples a step used by an estimator may have."""


def fail_steps(source: str, kind: str, steps: list[tuple[int, int]]) -> CalibrationError:
    """The error for steps with too few samples: ``[(step, samples), ...]``."""
    k, n = steps[0]
    what = "no samples" if n == 0 else f"only {n} sample(s)"
    return CalibrationError(f"{source}, step {k}: {what} of the {kind} outputs; expected at "
                            f"least {MIN_STEP_SAMPLES} per step used by the calibration")


def gyro_rate_test(problem: GyroProblem) -> RateTestFit:
    """Least-squares gains ``a = h̃/SF`` from the paired rate steps (calibrate stage 2).

    Raises
    ------
    CalibrationError
        A paired step with fewer than :data:`MIN_STEP_SAMPLES` samples, no pairs, or pairs
        that do not excite three body axes.
    """
    nums, cnt = problem.step_numbers, problem.step_count
    used = sorted({j for p in problem.pairs for j in p})
    few = [(nums[j], int(cnt[j])) for j in used if cnt[j] < MIN_STEP_SAMPLES]
    if few:
        raise fail_steps(problem.source, "gyro", few)
    return rate_test(problem.step_u, np.maximum(cnt, 1), problem.step_x, list(problem.pairs),
                     step_numbers=list(nums), source=problem.source)


@dataclass(frozen=True)
class LinearFit:
    """Gains, offsets (and regressor coefficients) of every gyro (calibrate stage 3).

    Attributes
    ----------
    bias_steps : tuple of int
        0-based step positions with enough samples, used by the offsets and residuals.
    op : ndarray, shape (4 + m, 2S)
        ``[a; c; β] = op @ ū_seg`` (explicit Earth-rate model).
    op_turns : ndarray, shape (4 + m, 2S), or None
        The same with seed 000's whole-turn offset (None without whole outer turns).
    theta : ndarray, shape (4 + m, n)
        ``op @ ū_seg``.
    theta_turns : ndarray, shape (4 + m, n), or None
        ``op_turns @ ū_seg``.
    inv_count : ndarray, shape (2S,)
        1/N per segment (0 for empty segments).
    """

    bias_steps: tuple[int, ...]
    op: np.ndarray
    op_turns: np.ndarray | None
    theta: np.ndarray
    theta_turns: np.ndarray | None
    inv_count: np.ndarray

    @property
    def a(self) -> np.ndarray:
        """Gains h̃/SF, shape (n, 3), raw per rad/s."""
        return self.theta[:3].T

    @property
    def c(self) -> np.ndarray:
        """Offsets b/SF, shape (n,), raw."""
        return self.theta[3]

    @property
    def beta(self) -> np.ndarray:
        """Regressor coefficients, shape (n, m), raw per regressor unit."""
        return self.theta[4:].T

    @property
    def Q(self) -> np.ndarray:
        """White-noise covariance factor ``op·diag(1/N)·opᵀ`` (4 + m, 4 + m)."""
        return (self.op * self.inv_count) @ self.op.T

    @property
    def Q_turns(self) -> np.ndarray | None:
        """The same for ``op_turns``."""
        if self.op_turns is None:
            return None
        return (self.op_turns * self.inv_count) @ self.op_turns.T



def _bias_weights(problem: GyroProblem) -> tuple[tuple[int, ...], np.ndarray]:
    S, cnt, cnt_seg = problem.n_steps, problem.step_count, problem.seg_count
    bias_steps = tuple(j for j in range(S) if cnt[j] >= MIN_STEP_SAMPLES)
    w = np.zeros(2 * S)
    for j in bias_steps:
        w[2 * j:2 * j + 2] = cnt_seg[2 * j:2 * j + 2]
    return bias_steps, w


def _joint_operator(problem: GyroProblem, w: np.ndarray) -> np.ndarray:
    """Weighted least squares of ``ū_seg = a·x̄_seg + c + β·z̄_seg`` (rows a, c, β)."""
    use = w > 0
    X = np.hstack([np.nan_to_num(problem.seg_x), np.ones((w.size, 1)),
                   np.nan_to_num(problem.seg_z)])
    Xw = X[use] * w[use, None]
    A = Xw.T @ X[use]
    if np.linalg.matrix_rank(A, tol=1e-10 * max(np.abs(A).max(), 1e-300)) < A.shape[0]:
        raise CalibrationError(f"{problem.source}: the regressors "
                               f"{', '.join(problem.regressor_names)} are collinear with the "
                               "inputs or each other over the steps; expected independent "
                               "columns")
    op = np.zeros((X.shape[1], w.size))
    op[:, use] = np.linalg.solve(A, Xw.T)
    return op


def _turn_rows(problem: GyroProblem, op_model: np.ndarray,
               bias_method: str) -> np.ndarray | None:
    """Operator with seed 000's whole-turn offset in row 3 (None without whole turns)."""
    tw = problem.turns
    if not tw.steps:
        if bias_method == "turns":
            raise CalibrationError(
                f"{problem.source}: bias method 'turns' needs outer-axis rate steps of at "
                "least one whole turn; the session has none"
                + (f" (steps {', '.join(map(str, tw.short_steps))} are shorter)"
                   if tw.short_steps else ""))
        return None
    S = problem.n_steps
    w_t = np.zeros(2 * S)
    w_t[1::2] = problem.seg_count[1::2]
    w_t /= w_t.sum()
    row = offset_operator(w_t, problem.seg_xturn, op_model[:3])
    if problem.seg_z is not None and problem.n_regressors:
        row = row - (w_t @ np.nan_to_num(problem.seg_z)) @ op_model[4:]
    out = op_model.copy()
    out[3] = row
    return out


def fit_offsets(problem: GyroProblem, rt: RateTestFit, bias_method: str = "model") -> LinearFit:
    """Offsets of every gyro with the rate-test gains (calibrate stage 3).

    Without regressors: ``a`` from the rate test and ``c`` from the explicit model over every
    bias step (:func:`calibration.bias.offset_operator`); with regressors: the joint least
    squares of the module docstring. Both also with seed 000's whole-turn offset.

    Raises
    ------
    CalibrationError
        ``bias_method="turns"`` without whole outer turns; collinear regressors.
    """
    bias_steps, w = _bias_weights(problem)
    if problem.regressors is None:
        op_a = rt.op @ problem.frac                        # (3, 2S) over segments
        P_model = np.vstack([op_a, offset_operator(w / w.sum(), problem.seg_x, op_a)])
    else:
        P_model = _joint_operator(problem, w)
    P_turns = _turn_rows(problem, P_model, bias_method)
    u0 = np.nan_to_num(problem.seg_u)
    cnt_seg = problem.seg_count
    inv_cnt = np.where(cnt_seg > 0, 1.0 / np.maximum(cnt_seg, 1), 0.0)
    return LinearFit(bias_steps=bias_steps, op=P_model, op_turns=P_turns,
                     theta=P_model @ u0, inv_count=inv_cnt,
                     theta_turns=None if P_turns is None else P_turns @ u0)
