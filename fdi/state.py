"""The arrays the compiled monitor kernel reads and writes, and the names of their slots.

The kernel (:mod:`fdi.kernel`) is compiled once for one signature: a handful of float64 and
int64 arrays. Their slots are named here; the kernel, the windows, the CUSUM bank and the
monitor use the names, never bare numbers.

Per healthy set (constants, :class:`KernelSet`, built once per set by :func:`pack_set`):

- ``sensors`` (:data:`SENSOR_COLS`, n; one row per quantity): per sensor the compensation
  y = sf·u − bias, the raw health bounds lo < u < hi, whether it is in the set, Σ_ii,
  h_iᵀ P h_i (P = G Σ Gᵀ, for re-admission), the calibrated axis h_i, the six
  coefficients of ρ_i = ω̂ᵀC_iω̂/Σ_ii and the timing-jitter coefficient τ_i²·fs²/Σ_ii of
  the term τ_i²(h_iᵀω̇̂)²/Σ_ii (zero outside the set).
- ``scales`` (K_w, :data:`SCALE_COLS`): per dyadic window w the χ² threshold T_w,
  1/(w·f_w), κ/f_w, 1 + w·β/f_w and the clearing threshold (hysteresis).
- ``mats`` (3·df + 3, n): the parity matrix V (rows 0 … df−1), the reconstruction matrix G
  (rows df … df+2), the lower-triangular whitening A (rows df+3 …, first df columns) and the
  unit whitened parity columns u_i/|u_i| (rows 2·df+3 …, column i for sensor i).
- ``fconst``, ``iconst``: scalars (κ, β, ν, h, the protection-level constants, limits).

Detector state (:class:`DetectorState`):

- ``windows`` (R + 1, df + 1): rows 0 … R−1 the ring of the last R cumulative sums
  c_t = Σ_{s≤t} (z_s, ρ_s) (seed 000's multi-resolution means as differences of c),
  row R the current c_t.
- ``cusum`` (4, n): per sensor the two one-sided random walks S⁺, S⁻ and their running
  minima; the CUSUM statistic is g = S − min S (Page's recursion written so).
- ``sensor`` (n, 4): last raw value, time of the latest valid sample, start of good
  behaviour (re-admission), length of the run of identical values.
- ``counters`` (int64): ring position, samples in the windows, detection flags and run
  lengths, where and why the kernel stopped, the health verdict per sensor.

The kernel takes each group whole as one flat array (the set's constants: ``KernelSet.packed``;
the float state: ``DetectorState.values``, which also holds the kernel's scratch vectors),
because numba's dispatch costs about 45 ns per array argument and :meth:`Monitor.step` pays
it on every sample; the named 2-D arrays above are views of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba.extending import register_jitable

from fdi.blocks import CAPABILITY_CODE as _CAPABILITY_CODE

__all__ = [
    "CAPABILITY_CODE",
    "DetectorState",
    "KernelSet",
    "OutLayout",
    "pack_set",
    "set_layout",
    "state_layout",
]

# ---------------------------------------------------------------- sensors (SENSOR_COLS, n)
SF, BIAS, LO, HI, IN_SET, SIGMA_II, H_P_H, AXIS0 = range(8)
RHO_COEF0 = AXIS0 + 3                       # six coefficients of ρ_i
JITTER_COEF = RHO_COEF0 + 6                 # τ_i²·fs²/Σ_ii: ρ_i += it·(h_iᵀΔω̂)²
SENSOR_COLS = JITTER_COEF + 1

# ---------------------------------------------------------------- scales (K_w, SCALE_COLS)
WINDOW, THRESHOLD, CHI2_SCALE, RHO_GAIN, OFFSET_GAIN, CLEAR_THRESHOLD = range(6)
SCALE_COLS = 6

# ---------------------------------------------------------------- fconst
(KAPPA, BETA, NU, CUSUM_H, CUSUM_CLEAR, PL_A, PL_B, PL_C, PL_D, PL_E, STALE_TIMEOUT_S,
 READMIT_DWELL_S) = range(12)
F_SLOTS = 12

# ---------------------------------------------------------------- iconst
DF, N_WINDOWS, HAS_CUSUM, CAPABILITY, HAS_OMEGA, STUCK_COUNT, PERSISTENCE, CLEAR_SAMPLES, \
    READMISSION, N_SENSORS, ASK_ISOLATE = range(11)
I_SLOTS = 11
CAPABILITY_CODE = _CAPABILITY_CODE
"""Capability name → code: :data:`fdi.blocks.CAPABILITY_CODE` (positions in the one table,
:data:`fdi.answer.CAPABILITIES`)."""

# ---------------------------------------------------------------- cusum (4, n)
S_UP, MIN_UP, S_DOWN, MIN_DOWN = range(4)

# ---------------------------------------------------------------- sensor state (n, 4)
LAST_RAW, LAST_VALID_T, GOOD_SINCE_T, SAME_RUN = range(4)

# ---------------------------------------------------------------- counters
(STARTED, RING_POS, WINDOW_COUNT, DETECTED, DETECTED_ROWS, ALARM_RUN, CLEAR_RUN, STOP_ROW,
 STOP_CODE, FIRED, READMIT_SENSOR, PHASE, HAS_VALID, HAS_PARITY, RING_LEN) = range(15)
HEALTH0 = 15                                # + i: health verdict of sensor i this sample

# where the kernel stops (STOP_CODE) and hands a sample to the monitor
STOP_NONE, STOP_HEALTH, STOP_READMIT, STOP_INCOMPLETE, STOP_DETECTED, STOP_ISOLATE = \
    0, 1, 2, 3, 4, 8
STOP_CLEARED = 16                           # a detection cleared (after its sample)
# added to the stop code that fdi.kernel.advance returns while a detection is active
RETURN_DETECTED = 32
STOP_MASK = 31                              # the stop code in advance's return value
# PHASE: where the kernel resumes a stopped sample
PHASE_HEALTH, PHASE_READMIT, PHASE_PARITY = 0, 1, 2
# health verdicts
HEALTH_OK, HEALTH_RANGE, HEALTH_NONFINITE, HEALTH_STUCK, HEALTH_STALE = range(5)
HEALTH_REASON = {HEALTH_RANGE: "range", HEALTH_NONFINITE: "nonfinite", HEALTH_STUCK: "stuck",
                 HEALTH_STALE: "stale"}

# ---------------------------------------------------------------- output row
OMEGA0, PROTECTION = 0, 3
STATS0 = 4


@dataclass(frozen=True)
class OutLayout:
    """Columns of one output row: ω̂ (3), protection level, K statistics, K thresholds and
    (optionally) the parity vector padded to n − 3."""

    K: int
    n_parity: int

    @property
    def thresholds0(self) -> int:
        """First threshold column."""
        return STATS0 + self.K

    @property
    def parity0(self) -> int:
        """First parity column."""
        return STATS0 + 2 * self.K

    def width(self, parity: bool) -> int:
        """Columns of a row with or without the parity vector."""
        return self.parity0 + (self.n_parity if parity else 0)


@dataclass(frozen=True, eq=False)
class KernelSet:
    """The constants of one healthy set in the kernel's layout (see the module docstring).

    ``packed`` is the one array the kernel reads (fewer arguments per call: numba's dispatch
    costs ~45 ns per array); the other fields are views of it, in the order of
    :func:`set_layout`: ``fconst`` | ``iconst`` (as float64) | ``sensors`` | ``scales`` |
    ``mats``.
    """

    packed: np.ndarray
    sensors: np.ndarray
    scales: np.ndarray
    mats: np.ndarray
    fconst: np.ndarray
    iconst: np.ndarray


SET_ICONST0 = F_SLOTS                       # iconst slots in the packed set (as float64)
SET_SENSORS0 = F_SLOTS + I_SLOTS            # first entry of ``sensors`` in the packed set


@register_jitable(inline="always")
def set_layout(n: int, df: int, nw: int) -> tuple[int, int, int]:
    """Offsets of ``scales``, ``mats`` and the end in the packed set of n sensors, parity
    dimension df and nw window scales (``sensors`` starts at :data:`SET_SENSORS0`)."""
    o_scales = SET_SENSORS0 + n * SENSOR_COLS
    o_mats = o_scales + nw * SCALE_COLS
    return o_scales, o_mats, o_mats + (3 * df + 3) * n


def pack_set(model, H: np.ndarray, sigma_diag: np.ndarray, lo: tuple[float, ...],
             hi: tuple[float, ...], settings, thresholds) -> KernelSet:
    """Lay out a :class:`fdi.reconstruction.SetModel` for the kernel.

    Parameters
    ----------
    model : SetModel
    H : ndarray, shape (n, 3)
        Calibrated axes.
    sigma_diag : ndarray, shape (n,)
        Noise variances Σ_ii (SI²).
    lo, hi : tuple of float
        Raw health bounds per sensor.
    settings : MonitorSettings
    thresholds : Thresholds
    """
    n = H.shape[0]
    df = model.df
    sensors = np.zeros((n, SENSOR_COLS))
    sensors[:, SF] = model.sf
    sensors[:, BIAS] = model.bias
    sensors[:, LO] = lo
    sensors[:, HI] = hi
    sensors[list(model.idx), IN_SET] = 1.0
    sensors[:, SIGMA_II] = sigma_diag
    cov = np.nan_to_num(np.asarray(model.cov, float))
    sensors[:, H_P_H] = np.einsum("ia,ab,ib->i", H, cov, H)
    sensors[:, AXIS0:AXIS0 + 3] = H
    sensors[:, RHO_COEF0:RHO_COEF0 + 6] = model.cal_coef
    # the kernel's dense loops need zeros (+0.0) outside the set: ρ coefficients, V and G
    out_of_set = [i for i in range(n) if i not in model.idx]
    if model.jit_coef is not None:
        sensors[:, JITTER_COEF] = model.jit_coef
    sensors[out_of_set, RHO_COEF0:RHO_COEF0 + 7] = 0.0
    nw = len(thresholds.scales)
    scales = np.zeros((nw, SCALE_COLS))
    scales[:, WINDOW] = thresholds.scales
    scales[:, THRESHOLD] = model.thr
    scales[:, CHI2_SCALE] = model.chi2_scale
    scales[:, RHO_GAIN] = model.rho_gain
    scales[:, OFFSET_GAIN] = model.offset_gain
    scales[:, CLEAR_THRESHOLD] = [settings.clear_ratio * t for t in model.thr]
    mats = np.zeros((3 * df + 3, n))
    mats[:df] = model.V
    mats[df:df + 3] = model.G
    mats[df + 3:2 * df + 3, :df] = model.A
    if df:
        norms = np.linalg.norm(model.U, axis=0)
        unit = np.where(norms > 0, model.U / np.where(norms > 0, norms, 1.0), 0.0)
        mats[2 * df + 3:, list(model.idx)] = unit
    mats[:df + 3, out_of_set] = 0.0
    fconst = np.zeros(F_SLOTS)
    fconst[KAPPA] = model.kappa
    fconst[BETA] = model.beta
    fconst[NU] = thresholds.cusum_drift
    fconst[CUSUM_H] = model.cusum_h
    fconst[CUSUM_CLEAR] = settings.clear_ratio * model.cusum_h
    pl = model.pl
    fconst[[PL_A, PL_B, PL_C, PL_D, PL_E]] = pl.a, pl.b, pl.c, pl.d, pl.e
    fconst[STALE_TIMEOUT_S] = settings.stale_timeout_s
    iconst = np.zeros(I_SLOTS, np.int64)
    iconst[DF] = df
    iconst[N_WINDOWS] = nw
    iconst[HAS_CUSUM] = thresholds.detector != "windows"
    iconst[CAPABILITY] = CAPABILITY_CODE[model.capability]
    iconst[HAS_OMEGA] = model.capability != "none"
    iconst[STUCK_COUNT] = settings.stuck_count
    iconst[PERSISTENCE] = settings.persistence
    iconst[CLEAR_SAMPLES] = settings.clear_samples
    iconst[READMISSION] = bool(settings.readmission)
    iconst[N_SENSORS] = n
    # persistent alarms go to the monitor's isolation test wherever it can tell hypotheses
    # apart at all (df ≥ 2): a set that isolates may exclude, one that only detects narrows
    # its suspects (fdi.monitor)
    iconst[ASK_ISOLATE] = df >= 2 and model.capability in ("isolate", "detect")
    fconst[READMIT_DWELL_S] = settings.readmit_dwell_s
    o_scales, o_mats, end = set_layout(n, df, nw)
    packed = np.zeros(end)
    packed[:F_SLOTS] = fconst
    packed[SET_ICONST0:SET_SENSORS0] = iconst
    packed[SET_SENSORS0:o_scales] = sensors.T.ravel()      # one row per quantity
    packed[o_scales:o_mats] = scales.ravel()
    packed[o_mats:end] = mats.ravel()
    return KernelSet(packed, packed[SET_SENSORS0:o_scales].reshape(SENSOR_COLS, n),
                     packed[o_scales:o_mats].reshape(nw, SCALE_COLS),
                     packed[o_mats:end].reshape(3 * df + 3, n), packed[:F_SLOTS], iconst)


SENSOR_STATE_COLS = 4
# rows the kernel compensates ahead (independent of the detector state; see fdi.kernel)
BLOCK_ROWS = 32


@register_jitable(inline="always")
def state_layout(n: int, ring: int) -> tuple[int, int, int, int]:
    """Offsets in the detector's float state of the CUSUM bank, the kernel's scratch
    (y, p, z: n each; ω̂: 3; the ω̂ of the last completed sample and of the one before it:
    3 each, at 3n + 3 and 3n + 6 after the scratch start; then (z, ρ) of :data:`BLOCK_ROWS` rows,
    n + 1 each), the
    windows and the end (``sensor`` starts at 0); the windows take (R + 1)·(n + 1) entries,
    room for any parity dimension df ≤ n."""
    o_cusum = n * SENSOR_STATE_COLS
    o_scratch = o_cusum + 4 * n
    o_windows = o_scratch + 3 * n + 9 + BLOCK_ROWS * (n + 1)
    return o_cusum, o_scratch, o_windows, o_windows + (ring + 1) * (n + 1)


class DetectorState:
    """Mutable state of the recursion (see the module docstring for the layout).

    The float state is one array, ``values`` (the kernel takes it whole); ``sensor``,
    ``cusum`` and ``windows`` are views of it, laid out by :func:`state_layout`.

    Parameters
    ----------
    n : int
        Sensors.
    ring : int
        Ring length R = longest window + 1.
    """

    def __init__(self, n: int, ring: int) -> None:
        self.n = n
        self.ring = ring
        o_cusum, o_scratch, self._o_windows, end = state_layout(n, ring)
        self.values = np.zeros(end)
        self.sensor = self.values[:o_cusum].reshape(n, SENSOR_STATE_COLS)
        self.sensor[:, LAST_RAW] = np.nan
        self.sensor[:, LAST_VALID_T] = np.nan
        self.sensor[:, GOOD_SINCE_T] = np.nan
        self.cusum = self.values[o_cusum:o_scratch].reshape(4, n)
        o_prev = o_scratch + 3 * n + 3
        self.omega_prev = self.values[o_prev:o_prev + 3]
        """ω̂ of the last completed sample (rad/s; NaN before the first): the jitter term's
        ω̇̂ = (ω̂_t − ω̂_{t−1})·fs (:mod:`fdi.kernel`)."""
        self.values[o_prev:o_prev + 6] = np.nan       # and the ω̂ before it
        self.counters = np.zeros(HEALTH0 + n, np.int64)
        self.counters[RING_LEN] = ring
        self.new_set(0)

    def new_set(self, df: int) -> None:
        """Empty windows, CUSUM and detection for a new healthy set of parity dimension df."""
        o = self._o_windows
        self.values[o:] = 0.0
        self.windows = self.values[o:o + (self.ring + 1) * (df + 1)].reshape(self.ring + 1,
                                                                             df + 1)
        self.cusum[:] = 0.0
        c = self.counters
        c[[RING_POS, WINDOW_COUNT, DETECTED, DETECTED_ROWS, ALARM_RUN, CLEAR_RUN]] = 0

    @property
    def cumulative(self) -> np.ndarray:
        """Current cumulative sums c_t of (z, ρ), shape (df + 1,)."""
        return self.windows[self.ring]

    def window_sum(self, w: int) -> np.ndarray:
        """Σ z over the last ``w`` complete samples, shape (df,)."""
        pos = int(self.counters[RING_POS]) - w
        old = self.windows[pos % self.ring]
        cur = self.windows[self.ring]
        return cur[:-1] - old[:-1]

    def cusum_scores(self, m_idx: tuple[int, ...]) -> np.ndarray:
        """CUSUM statistic max(S⁺ − min S⁺, S⁻ − min S⁻) per healthy sensor."""
        c = self.cusum[:, list(m_idx)]
        return np.maximum(c[S_UP] - c[MIN_UP], c[S_DOWN] - c[MIN_DOWN])
