"""The prior an in-flight calibration holds what the motion does not excite at, and the mounting.

Each IMU j is modelled against the reference as ``y_j = (I + E_j)·R_j·y_ref + c_j``:
``R_j`` its nominal mounting, a signed permutation (a rotation by multiples of 90°; identity
for autopilot logs, which are already in the body frame), and ``E_j`` the small
misalignment, scale and non-orthogonality the fit estimates. The prior on ``E_j`` is
Gaussian with mean 0 and the sds of :class:`Prior` (stated tolerances, read as 1σ): the
rotation ±2°, the relative scale ±3 % (a datasheet's scale tolerance), the
non-orthogonality ±2 % (cross-axis sensitivity), the time offset ±1 sample. The fit is the
posterior mode (:func:`calibration.inflight.regression.stacked_ridge`): a parameter the
motion excites is estimated from the data, one it does not stays at the prior with the
prior's σ in its covariance, and the calibration file says which
(``extra.inflight.imus.<imu>.parameters``).

:func:`nearest_mounting` finds ``R_j`` from the flight: the signed permutation nearest the
least-squares gain matrix on the reference axes the flight moves, the one nearest identity
among those that agree there (an axis the flight does not move cannot choose).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from fdi.errors import ConfigError

__all__ = ["PARAMETERS", "Prior", "mounting_text", "nearest_mounting",
           "signed_permutations"]

PARAMETERS = ("rotation x", "rotation y", "rotation z", "scale x", "scale y", "scale z",
              "nonorthogonality xy", "nonorthogonality xz", "nonorthogonality yz")
"""Names of the parameters of ``E`` (the order of :func:`calibration.inflight.fit.decompose`)."""


@dataclass(frozen=True)
class Prior:
    """Prior sds (1σ) of the parameters the motion may not excite.

    Attributes
    ----------
    misalignment_sd : float
        Rotation about each axis (rad); default 2°.
    scale_sd : float
        Relative scale factor (fraction); default 0.03.
    nonorthogonality_sd : float
        Non-orthogonality (rad); default 0.02.
    time_offset_sd_s : float or None
        Time offset (s); None: one sample interval.
    """

    misalignment_sd: float = math.radians(2.0)
    scale_sd: float = 0.03
    nonorthogonality_sd: float = 0.02

    time_offset_sd_s: float | None = None

    def __post_init__(self) -> None:
        for k in ("misalignment_sd", "scale_sd", "nonorthogonality_sd"):
            v = getattr(self, k)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"prior {k} must be a positive finite number, got {v!r}")
        t = self.time_offset_sd_s
        if t is not None and not (math.isfinite(t) and t > 0):
            raise ConfigError(f"prior time_offset_sd_s must be positive and finite, got {t!r}")

    def sds(self) -> np.ndarray:
        """Prior sds of the nine parameters of :data:`PARAMETERS`, shape (9,)."""
        return np.array([self.misalignment_sd] * 3 + [self.scale_sd] * 3
                        + [self.nonorthogonality_sd] * 3)

    def tau_sd(self, sample_rate_hz: float) -> float:
        """Prior sd of the time offset (s)."""
        return (1.0 / float(sample_rate_hz) if self.time_offset_sd_s is None
                else float(self.time_offset_sd_s))

    def to_dict(self, sample_rate_hz: float) -> dict[str, float]:
        """JSON-ready (mrad, fraction, ms)."""
        return {"misalignment_mrad_sd": 1e3 * self.misalignment_sd, "scale_sd": self.scale_sd,
                "nonorthogonality_mrad_sd": 1e3 * self.nonorthogonality_sd,
                "time_offset_ms_sd": 1e3 * self.tau_sd(sample_rate_hz)}


def signed_permutations(proper: bool = True) -> list[np.ndarray]:
    """The 24 rotations by multiples of 90° (48 signed permutations with ``proper=False``),
    identity first."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            P[range(3), perm] = signs
            if proper and np.linalg.det(P) < 0:
                continue
            out.append(P)
    out.sort(key=lambda P: -np.trace(P))          # identity (trace 3) first
    return out


def _angle_deg(R: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def nearest_mounting(y_ref: np.ndarray, y: np.ndarray, *, excitation_min: float = 10.0
                     ) -> tuple[np.ndarray, dict[str, float]]:
    """The signed-permutation mounting ``R`` with ``y ≈ R·y_ref + c`` (module docstring).

    The gain matrix ``Â`` is fitted by least squares (with a bias); a reference axis whose
    rate varies by at least ``excitation_min`` times the noise (the fit's residual sd over
    √2) can tell the mountings apart, the others cannot. R is the rotation by multiples of
    90° with the largest ``Σ_m R[:, m]·Â[:, m]`` over the excited axes m; of the rotations
    that agree with it on those axes, the one nearest identity (with no excited axis:
    identity; with one, a turn about it stays unresolved and identity's is kept).

    Parameters
    ----------
    y_ref, y : ndarray, shape (N, 3)
        Reference and IMU rates (rad/s), finite rows only.
    excitation_min : float

    Returns
    -------
    R : ndarray, shape (3, 3)
    info : dict
        ``angle_deg`` of R, ``excited`` (number of reference axes that choose it),
        ``rms`` of the least-squares residual (rad/s).
    """
    X = np.hstack([y_ref, np.ones((y_ref.shape[0], 1))])
    B, *_ = np.linalg.lstsq(X, y, rcond=None)
    A = B[:3].T
    res = y - X @ B
    noise = float(np.median(np.std(res, axis=0))) / math.sqrt(2)
    exc = np.std(y_ref, axis=0) >= excitation_min * max(noise, 1e-12)
    cands = signed_permutations()
    score = np.array([float(np.sum(P[:, exc] * A[:, exc])) for P in cands])
    best = cands[int(np.argmax(score))]
    same = [P for P in cands if np.array_equal(P[:, exc], best[:, exc])]
    R = min(same, key=_angle_deg)
    return R, {"angle_deg": _angle_deg(R), "excited": float(np.sum(exc)),
               "rms": float(np.sqrt(np.mean(res**2)))}


def mounting_text(R: np.ndarray) -> str:
    """``"x←-y, y←+x, z←+z (90° about z)"``: which reference axis each IMU axis reads."""
    R = np.asarray(R)
    parts = []
    for k in range(3):
        m = int(np.argmax(np.abs(R[k])))
        parts.append(f"{'xyz'[k]}<-{'+' if R[k, m] > 0 else '-'}{'xyz'[m]}")
    ang = _angle_deg(R)
    if ang < 1e-9:
        return "identity"
    w, V = np.linalg.eig(R)
    ax = np.real(V[:, int(np.argmin(np.abs(w - 1)))])
    ax = ax / np.linalg.norm(ax)
    if ax[int(np.argmax(np.abs(ax)))] < 0:
        ax = -ax
    # sign of the angle about ax: the skew part of R
    skew = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sgn = -1.0 if float(skew @ ax) < -1e-9 else 1.0
    axis = "[" + ", ".join(f"{v:+.2f}" for v in ax) + "]"
    return f"{', '.join(parts)} ({sgn * ang:+.0f} deg about {axis})"
