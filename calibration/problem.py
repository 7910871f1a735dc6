"""Stage 1 of the calibration: the session as segment means (the least-squares problem).

Every estimator of :mod:`calibration.calibrate` is linear in *segment means*: a segment is
a step, or for an outer-axis rate step its whole-turn window and the rest (seed 000 Eq. 20).
:func:`gyro_problem` computes those means of the raw gyro outputs and of the exact
body-frame inputs (table rate plus Earth rate as modelled); :func:`accel_problem` the means
of the raw accelerometer outputs and of the specific force over the position steps.

Extra regressors (for the diagnosis of effects the model lacks)
--------------------------------------------------------------
``GyroProblem.with_regressors(columns, names)`` returns the same problem with extra
per-sample columns ``z`` (N, m), shared by every sensor of the set. The gyro model becomes
``u_i = a_i·x + c_i + β_i·z`` and :func:`calibration.linear_fit.fit_offsets` estimates
``(a, c, β)`` jointly by least squares over the segment means of the bias steps, weighted
by their sample counts (a problem without regressors keeps the papers' two-stage estimator:
rate test, then offsets). A sensor-dependent regressor is written as several shared
columns (e.g. the three components of the specific force for a g-sensitivity vector), or
fitted once per sensor with that sensor's column, keeping that sensor's result.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calibration.bias import TurnWindows, turn_windows
from calibration.residuals import segment_means
from calibration.session import Session, Step
from fdi.errors import CalibrationError
from fdi.units import EARTH_RATE

__all__ = ["AccelProblem", "GyroProblem", "accel_problem", "check_finite", "gyro_problem",
           "rate_pairs"]


def check_finite(source: str, kind: str, raw: np.ndarray, step: np.ndarray) -> None:
    """Refuse non-finite samples, naming the step, sensor and sample (1-based)."""
    bad = ~np.all(np.isfinite(raw), axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        col = int(np.flatnonzero(~np.isfinite(raw[i]))[0])
        raise CalibrationError(f"{source}, step {int(step[i])}: non-finite {kind} sample "
                               f"(sensor {col + 1}, sample {i + 1}); expected finite numbers")


def rate_pairs(steps: Sequence[Step], pos: dict[int, int]) -> list[tuple[int, int]]:
    """Rate-step pairs as step positions (first occurrence minus its partner)."""
    rate = [s for s in steps if s.kind == "rate"]
    out, seen = [], set()
    if any(s.pair is not None for s in rate):
        for s in rate:
            if s.pair is None or s.pair not in pos:
                continue
            key = tuple(sorted((s.index, s.pair)))
            if key in seen:
                continue
            seen.add(key)
            out.append((pos[s.index], pos[s.pair]))
    else:                                  # seed 000 Eq. 18 / seed 001 Eq. 15: in order
        for s1, s2 in zip(rate[0::2], rate[1::2], strict=False):
            out.append((pos[s1.index], pos[s2.index]))
    return out


@dataclass(frozen=True)
class GyroProblem:
    """Segment means of a session's gyro outputs and inputs (stage 1).

    Shapes: N samples, n gyros, S steps, 2S segments (segment ``2j`` is step j outside its
    whole-turn window, ``2j+1`` inside), m extra regressors.

    Attributes
    ----------
    source : str
    step_numbers : tuple of int
        1-based step numbers in session order (S,).
    sample_rate_hz : float
    latitude_rad : float
    t : ndarray, shape (N,)
        Time (s).
    raw : ndarray, shape (N, n)
        Raw outputs.
    table_rate, earth_rate, specific_force : ndarray, shape (N, 3)
        Exact body inputs (rad/s, rad/s, m/s²).
    up : ndarray, shape (N, 3)
        Unit Up vector in the body frame.
    segment : ndarray of int, shape (N,)
        Segment of each sample (-1: step not in the session's step list).
    step_pos : ndarray of int, shape (N,)
        0-based step position of each sample (-1: none).
    turns : TurnWindows
    seg_count : ndarray of int, shape (2S,)
    seg_u : ndarray, shape (2S, n)
        Segment means of the raw outputs (NaN when empty).
    seg_x, seg_xturn : ndarray, shape (2S, 3)
        Segment means of the total input and of the table rate plus the vertical Earth rate.
    step_count : ndarray, shape (S,)
    frac : ndarray, shape (S, 2S)
        Step mean = ``frac @`` segment means.
    step_u : ndarray, shape (S, n)
    step_x : ndarray, shape (S, 3)
    pairs : tuple of (int, int)
        Rate-step pairs as 0-based step positions.
    regressors : ndarray, shape (N, m), or None
        Extra per-sample columns (see the module docstring); None: the papers' model.
    regressor_names : tuple of str
    seg_z : ndarray, shape (2S, m), or None
        Segment means of the regressors.
    """

    source: str
    step_numbers: tuple[int, ...]
    sample_rate_hz: float
    latitude_rad: float
    t: np.ndarray
    raw: np.ndarray
    table_rate: np.ndarray
    earth_rate: np.ndarray
    specific_force: np.ndarray
    up: np.ndarray
    segment: np.ndarray
    step_pos: np.ndarray
    turns: TurnWindows
    seg_count: np.ndarray
    seg_u: np.ndarray
    seg_x: np.ndarray
    seg_xturn: np.ndarray
    step_count: np.ndarray
    frac: np.ndarray
    step_u: np.ndarray
    step_x: np.ndarray
    pairs: tuple[tuple[int, int], ...]
    regressors: np.ndarray | None = None
    regressor_names: tuple[str, ...] = ()
    seg_z: np.ndarray | None = None

    @property
    def x(self) -> np.ndarray:
        """Total input (table rate + Earth rate), shape (N, 3), rad/s."""
        return self.table_rate + self.earth_rate

    @property
    def n_steps(self) -> int:
        """S."""
        return len(self.step_numbers)

    @property
    def n_regressors(self) -> int:
        """m (0 without regressors)."""
        return 0 if self.regressors is None else self.regressors.shape[1]

    def with_regressors(self, columns: np.ndarray, names: Sequence[str]) -> GyroProblem:
        """The same problem with extra regressor columns (model ``u = a·x + c + β·z``).

        Parameters
        ----------
        columns : ndarray, shape (N,) or (N, m)
            Per-sample regressors, any unit (β comes in raw units per unit of z).
        names : sequence of str
            One name per column.

        Raises
        ------
        CalibrationError
            Wrong shape, name count or non-finite values.
        """
        z = np.asarray(columns, float)
        if z.ndim == 1:
            z = z[:, None]
        names = tuple(str(s) for s in names)
        if z.ndim != 2 or z.shape[0] != self.raw.shape[0] or z.shape[1] != len(names):
            raise CalibrationError(f"{self.source}: regressors of shape {z.shape} with "
                                   f"{len(names)} name(s); expected ({self.raw.shape[0]}, m) "
                                   "with m names")
        if not np.all(np.isfinite(z)):
            raise CalibrationError(f"{self.source}: non-finite regressor values; expected "
                                   "finite numbers")
        _, (seg_z,) = segment_means(self.segment, self.seg_count.size, z)
        return dataclasses.replace(self, regressors=z, regressor_names=names, seg_z=seg_z)


def gyro_problem(session: Session) -> GyroProblem:
    """Segment and step means of the gyro outputs and inputs (calibrate stage 1).

    Raises
    ------
    CalibrationError
        Non-finite samples.
    """
    src = session.source
    nums = [s.index for s in session.steps]
    pos = {k: j for j, k in enumerate(nums)}
    S = len(nums)
    lat = np.deg2rad(session.latitude_deg)
    raw = np.asarray(session.raw_gyro, float)
    check_finite(src, "gyro", raw, session.step)
    wt, we, fb = session.inputs()
    up = fb / np.maximum(np.linalg.norm(fb, axis=1, keepdims=True), 1e-300)
    xt = wt + we
    tw = turn_windows(session.step, session.outer, session.inner_rate, session.outer_rate,
                      nums)
    step_pos = np.array([pos.get(int(k), -1) for k in np.unique(session.step)])
    _, inv = np.unique(session.step, return_inverse=True)
    spos = step_pos[inv]
    seg = np.where(spos >= 0, 2 * spos + tw.in_window, -1)
    xturn = wt + EARTH_RATE * np.sin(lat) * up            # vertical Earth rate only
    cnt_seg, (u_seg, xt_seg, xturn_seg) = segment_means(seg, 2 * S, raw, xt, xturn)
    cnt = cnt_seg[0::2] + cnt_seg[1::2]
    frac = np.zeros((S, 2 * S))
    for j in range(S):
        if cnt[j]:
            frac[j, 2 * j] = cnt_seg[2 * j] / cnt[j]
            frac[j, 2 * j + 1] = cnt_seg[2 * j + 1] / cnt[j]
    return GyroProblem(
        source=src, step_numbers=tuple(nums), sample_rate_hz=float(session.sample_rate_hz),
        latitude_rad=float(lat), t=np.asarray(session.t, float), raw=raw, table_rate=wt,
        earth_rate=we, specific_force=fb,
        up=up, segment=seg, step_pos=spos, turns=tw, seg_count=cnt_seg, seg_u=u_seg,
        seg_x=xt_seg, seg_xturn=xturn_seg, step_count=cnt, frac=frac,
        step_u=frac @ np.nan_to_num(u_seg), step_x=frac @ np.nan_to_num(xt_seg),
        pairs=tuple(rate_pairs(session.steps, pos)))


@dataclass(frozen=True)
class AccelProblem:
    """Position-step means of a session's accelerometer outputs (stage 1, accelerometers).

    Attributes
    ----------
    source : str
    step_numbers : tuple of int
        The K position steps (1-based).
    t : ndarray, shape (N,)
    raw : ndarray, shape (N, n)
    specific_force : ndarray, shape (N, 3)
    segment : ndarray of int, shape (N,)
        Position of each sample (0..K-1; -1: not a position step).
    count : ndarray of int, shape (K,)
    mean_u : ndarray, shape (K, n)
    mean_f : ndarray, shape (K, 3)
    """

    source: str
    step_numbers: tuple[int, ...]
    t: np.ndarray
    raw: np.ndarray
    specific_force: np.ndarray
    segment: np.ndarray
    count: np.ndarray
    mean_u: np.ndarray
    mean_f: np.ndarray


def accel_problem(session: Session, fb: np.ndarray) -> AccelProblem | None:
    """Position means of the accelerometers; None without accelerometers or ≥ 4 positions.

    Raises
    ------
    CalibrationError
        Non-finite samples.
    """
    if session.raw_accel is None or session.accel_config is None:
        return None
    pos_steps = [s.index for s in session.steps if s.kind == "position"]
    if len(pos_steps) < 4:
        return None
    raw = np.asarray(session.raw_accel, float)
    check_finite(session.source, "accelerometer", raw, session.step)
    lookup = {k: j for j, k in enumerate(pos_steps)}
    uniq, inv = np.unique(session.step, return_inverse=True)
    seg = np.array([lookup.get(int(k), -1) for k in uniq])[inv]
    cnt, (u_m, f_m) = segment_means(seg, len(pos_steps), raw, fb)
    return AccelProblem(source=session.source, step_numbers=tuple(pos_steps),
                        t=np.asarray(session.t, float), raw=raw,
                        specific_force=fb, segment=seg, count=cnt, mean_u=u_m, mean_f=f_m)
