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
- ``fconst``, ``iconst``: scalars (κ, β, ν, h, the protection-level constants, limits,
  the re-admission dwell and gate).

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
the float state: ``DetectorState.values``, which also holds the monitor's clock and the
kernel's scratch vectors),
because numba's dispatch costs about 45 ns per array argument and :meth:`Monitor.step` pays
it on every sample; the named 2-D arrays above are views of them, and the kernel's
scratch vectors y, p, z (n each), ω̂, the ω̂ of the last completed sample and of the one
before it (3 each) and the block of (z, ρ) rows compensated ahead (:data:`BLOCK_ROWS` rows of
n + 1) are further parts of ``DetectorState.values``.

Everything is named in one place: :data:`LAYOUT` holds the slots of every axis (and the
codes the kernel hands the monitor), :data:`SET_PARTS` and :data:`STATE_PARTS` the parts of
the two flat arrays. The module-level names (``SF``, ``KAPPA``, ``SCRATCH_Y``, …) are
derived from these tables, so are :func:`set_layout`, the views of :class:`KernelSet` and
:class:`DetectorState`, the kernel's views (:func:`span`) and the enumerators of the
generated C (:func:`c_enums`): a slot or a scratch vector is added by adding it to its
table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba.extending import register_jitable

from fdi.answer import TIME_STATUSES as _TIME_STATUSES
from fdi.blocks import CAPABILITY_CODE as _CAPABILITY_CODE
from fdi.detector import clear_thresholds

__all__ = [
    "BLOCK_ROWS",
    "CAPABILITY_CODE",
    "LAYOUT",
    "SET_PARTS",
    "STATE_PARTS",
    "DetectorState",
    "KernelSet",
    "Names",
    "OutLayout",
    "c_enums",
    "offset",
    "pack_set",
    "set_layout",
    "span",
    "state_size",
]


class Names:
    """Named integers of one kind, in order: the slots along one axis of a kernel array, or
    a set of codes.

    Every name becomes a module-level int of :mod:`fdi.state` (``from fdi.state import SF``;
    numba reads module-level ints as compile-time constants) and an enumerator of the
    generated C (:func:`c_enums`), so a slot is added in one place: its table in
    :data:`LAYOUT`.

    Parameters
    ----------
    title : str
        What the names are (a comment in the C).
    values : dict of str to int
    """

    def __init__(self, title: str, values: dict[str, int]) -> None:
        self.title = title
        self.values = dict(values)

    @classmethod
    def slots(cls, title: str, spec: str, end: str | None = None) -> Names:
        """Consecutive slots from 0: ``spec`` lists the names in order, ``NAME*k`` a slot k
        entries wide (the name is its first); ``end`` names the count."""
        values, at = {}, 0
        for item in spec.split():
            name, _, width = item.partition("*")
            values[name] = at
            at += int(width or 1)
        if end:
            values[end] = at
        return cls(title, values)

    def __getattr__(self, name: str) -> int:
        try:
            return self.__dict__["values"][name]
        except KeyError:
            raise AttributeError(name) from None


# ---------------------------------------------------------------------------- the table
BLOCK_ROWS = 32
"""Rows the kernel compensates ahead (independent of the detector state; see fdi.kernel)."""

SENSORS = Names.slots("sensors (SENSOR_COLS, n): one row per quantity",
                      "SF BIAS LO HI IN_SET SIGMA_II H_P_H AXIS0*3 RHO_COEF0*6 JITTER_COEF U_NORM2",
                      "SENSOR_COLS")
"""y = SF·u − BIAS; raw bounds; in the set; Σ_ii; h_iᵀPh_i; h_i; ρ_i's six coefficients;
τ_i²·fs²/Σ_ii (ρ_i += JITTER_COEF·(h_iᵀΔω̂)²); |u_i|², the squared norm of the sensor's
whitened parity column (the vibration test's physical comparison, +0.0 outside the set)."""
SCALES = Names.slots("scales (K_w, SCALE_COLS)",
                     "WINDOW THRESHOLD CHI2_SCALE RHO_GAIN OFFSET_GAIN CLEAR_THRESHOLD",
                     "SCALE_COLS")
FCONST = Names.slots("fconst", "KAPPA BETA NU CUSUM_H CUSUM_CLEAR PL_A PL_B PL_C PL_D PL_E "
                     "STALE_TIMEOUT_S READMIT_DWELL_S READMIT_GATE STALE_SAMPLES "
                     "MAX_TIME_STEP_S NOISE_GAIN NOISE_CLIP NOISE_BAND NOISE_MAX VIB_RATIO "
                     "VIB_LEVEL", "F_SLOTS")
"""... STALE_SAMPLES: stale_timeout_s × the thresholds' sample rate (the stale clock on the
sample count); MAX_TIME_STEP_S: the largest forward step of the time stamp taken as
plausible (:attr:`fdi.settings.MonitorSettings.max_time_step_s`); NOISE_*: the in-flight
noise scale (gain λ = 1/(noise_window_s·fs), clip, band, bound K); VIB_*: the vibration
test (:func:`fdi.kernel.noise_update`)."""
ICONST = Names.slots("iconst", "DF N_WINDOWS HAS_CUSUM CAPABILITY HAS_OMEGA STUCK_COUNT "
                     "PERSISTENCE CLEAR_SAMPLES READMISSION N_SENSORS ASK_ISOLATE "
                     "REBASE_SAMPLES VIB_DWELL VIB_ON", "I_SLOTS")
CUSUM = Names.slots("cusum (CUSUM_ROWS, n)", "S_UP MIN_UP S_DOWN MIN_DOWN", "CUSUM_ROWS")
SENSOR_STATE = Names.slots("sensor state (n, SENSOR_STATE_COLS)",
                           "LAST_RAW LAST_VALID_T GOOD_SINCE_T SAME_RUN MISSED_RUN",
                           "SENSOR_STATE_COLS")
"""LAST_VALID_T: time of the latest valid sample whose time stamp was good (NaN: unknown, a
valid sample at a bad time stamp; the stale clock then runs on MISSED_RUN alone);
MISSED_RUN: samples in a row without a valid sample of the sensor (the stale clock on the
sample count)."""
CLOCK = Names.slots("clock (CLOCK_SLOTS): the monitor's time base",
                    "LAST_GOOD_T CAND_T", "CLOCK_SLOTS")
"""LAST_GOOD_T: the latest good time stamp (NaN: none yet); CAND_T: the latest finite time
stamp that was not good (a candidate new time base, :func:`fdi.kernel.time_check`)."""
COUNTERS = Names.slots("counters (HEALTH0 + n)",
                       "STARTED RING_POS WINDOW_COUNT DETECTED DETECTED_ROWS ALARM_RUN "
                       "CLEAR_RUN STOP_ROW STOP_CODE FIRED READMIT_SENSOR PHASE HAS_VALID "
                       "HAS_PARITY RING_LEN HOLD_OPEN TIME_STATUS REBASE_RUN ZPREV_OK ENV_OUT "
                       "VIB_RUN VIB_SENSOR HEALTH0")
"""HOLD_OPEN: window count below which an open detection may not clear (set at envelope
re-entry: the windows refill first); TIME_STATUS: the time-stamp verdict of this sample
(:data:`TIME`); REBASE_RUN: bad but mutually consistent time stamps in a row (a new time
base after ``REBASE_SAMPLES``); ZPREV_OK: the state holds the whitened parity of the last
complete sample of this set (for the noise scale's differences); ENV_OUT: out of the
envelope (the monitor sets it: the noise scale and the vibration test wait); VIB_RUN,
VIB_SENSOR: samples in a row the same sensor passed the vibration test, and which;
HEALTH0 + i: the health verdict of sensor i this sample
(the last n counters)."""
OUT = Names.slots("output row", "OMEGA0*3 PROTECTION TIME_CODE STATS0")
"""ω̂ (3), the protection level, the time-stamp verdict (:data:`TIME`, as a float), then K
statistics, K thresholds, the parity (:class:`OutLayout`)."""
STOP = Names("stop codes", dict(STOP_NONE=0, STOP_HEALTH=1, STOP_READMIT=2,
                                STOP_INCOMPLETE=3, STOP_DETECTED=4, STOP_ISOLATE=8,
                                STOP_CLEARED=16, STOP_VIBRATION=32, STOP_MASK=63,
                                RETURN_DETECTED=64))
"""Where the kernel stops (``counters[STOP_CODE]``) and hands a sample to the monitor:
STOP_DETECTED | STOP_ISOLATE stop after the sample, STOP_CLEARED after a detection cleared,
STOP_VIBRATION (or-ed with the others) after a sensor passed the vibration test
(``counters[VIB_SENSOR]``);
:func:`fdi.kernel.advance` returns the stop code (STOP_MASK) plus RETURN_DETECTED while a
detection is active."""
PHASES = Names.slots("phase: where the kernel resumes a stopped sample",
                     "PHASE_HEALTH PHASE_READMIT PHASE_PARITY")
HEALTH = Names.slots("health verdicts",
                     "HEALTH_OK HEALTH_RANGE HEALTH_NONFINITE HEALTH_STUCK HEALTH_STALE")
TIME = Names.slots("time-stamp verdicts",
                   "TIME_OK TIME_NONFINITE TIME_BACKWARD TIME_JUMP TIME_REBASED")
"""Per sample: a good time stamp; NaN or ±inf; earlier than the last good one; more than
``max_time_step_s`` after it; the sample at which a run of bad but mutually consistent
time stamps became the new time base (good from there on). :func:`fdi.kernel.time_check`."""
LAYOUT = (SENSORS, SCALES, FCONST, ICONST, CUSUM, SENSOR_STATE, CLOCK, COUNTERS, OUT, STOP,
          PHASES, HEALTH, TIME)
"""Every table of named integers: their names are module-level ints of this module (as the
standard library's ``re`` exports its flags) and enumerators of the generated C."""


def _export(values: dict) -> None:
    """Make ``values`` module-level names; a name already taken (two tables naming one slot
    alike) is refused at import."""
    taken = values.keys() & globals().keys()
    if taken:
        raise RuntimeError(f"fdi.state: {sorted(taken)} named twice")
    globals().update(values)


for _names in LAYOUT:
    _export(_names.values)
del _names

HEALTH_REASON = {HEALTH.HEALTH_RANGE: "range", HEALTH.HEALTH_NONFINITE: "nonfinite",
                 HEALTH.HEALTH_STUCK: "stuck", HEALTH.HEALTH_STALE: "stale"}
TIME_STATUSES = _TIME_STATUSES
"""Time-stamp verdict names, in the order of :data:`TIME` (:data:`fdi.answer.TIME_STATUSES`)."""
CAPABILITY_CODE = _CAPABILITY_CODE
"""Capability name → code: :data:`fdi.blocks.CAPABILITY_CODE` (positions in the one table,
:data:`fdi.answer.CAPABILITIES`)."""


def _parts(spec: tuple[tuple[str, int, int, int], ...], last: str) -> dict[str, tuple]:
    """Consecutive parts of a flat array: ``(name, entries, per sensor, per scale)`` each,
    sizes linear in n and nw; ``last`` takes the rest (its size depends on more than n, nw).
    Each part becomes ``(at, at per sensor, at per scale, size, size per sensor, size per
    scale)``: the form :func:`span` reads."""
    out, at = {}, (0, 0, 0)
    for name, *size in spec:
        out[name] = (*at, *size)
        at = tuple(a + s for a, s in zip(at, size, strict=True))
    out[last] = (*at, 0, 0, 0)
    return out


SET_PARTS = _parts((("SET_FCONST", FCONST.F_SLOTS, 0, 0),
                    ("SET_ICONST", ICONST.I_SLOTS, 0, 0),
                    ("SET_SENSORS", 0, SENSORS.SENSOR_COLS, 0),
                    ("SET_SCALES", 0, 0, SCALES.SCALE_COLS)), "SET_MATS")
"""Parts of the packed constants of a set (:attr:`KernelSet.packed`); ``SET_MATS``, last,
holds (3·df + 3)·n entries."""
STATE_PARTS = _parts((("STATE_CLOCK", CLOCK.CLOCK_SLOTS, 0, 0),
                      ("STATE_NOISE", 1, 0, 0), ("STATE_ZPREV", 0, 1, 0),
                      ("STATE_VIB", 0, 1, 0),
                      ("STATE_SENSOR", 0, SENSOR_STATE.SENSOR_STATE_COLS, 0),
                      ("STATE_CUSUM", 0, CUSUM.CUSUM_ROWS, 0),
                      ("SCRATCH_Y", 0, 1, 0), ("SCRATCH_P", 0, 1, 0), ("SCRATCH_Z", 0, 1, 0),
                      ("SCRATCH_W", 3, 0, 0), ("SCRATCH_PREV", 3, 0, 0),
                      ("SCRATCH_BEFORE", 3, 0, 0),
                      ("SCRATCH_BLOCK", BLOCK_ROWS, BLOCK_ROWS, 0)), "STATE_WINDOWS")
"""Parts of the float detector state (:attr:`DetectorState.values`): the sensor history, the
CUSUM bank, the kernel's scratch (y, p, z; ω̂; the ω̂ of the last completed sample and of
the one before it; (z, ρ) of :data:`BLOCK_ROWS` rows, n + 1 each) and, last, the windows
((R + 1)·(n + 1) entries, room for any parity dimension df ≤ n)."""
_export(SET_PARTS)                          # SET_FCONST, …, SCRATCH_Y, …: tuples of ints
_export(STATE_PARTS)
_SCALES, _MATS, _WINDOWS = (SET_PARTS["SET_SCALES"], SET_PARTS["SET_MATS"],
                            STATE_PARTS["STATE_WINDOWS"])
SET_ICONST0 = SET_PARTS["SET_ICONST"][0]    # iconst slots in the packed set (as float64)
SET_SENSORS0 = SET_PARTS["SET_SENSORS"][0]  # first entry of ``sensors`` in the packed set


@register_jitable(inline="always")
def offset(part, n, nw):
    """Where ``part`` (an entry of :data:`SET_PARTS` or :data:`STATE_PARTS`) starts, for n
    sensors and nw window scales."""
    return part[0] + part[1] * n + part[2] * nw


def span(a, part, n, nw):
    """The entries of ``part`` in the flat array ``a`` (a view), for n sensors and nw window
    scales. (Plain Python: :mod:`fdi.kernel` compiles it inline, where a view may be
    returned without numba's reference counting.)"""
    o = offset(part, n, nw)
    return a[o:o + part[3] + part[4] * n + part[5] * nw]


@register_jitable(inline="always")
def set_layout(n: int, df: int, nw: int) -> tuple[int, int, int]:
    """Offsets of ``scales``, ``mats`` and the end in the packed set of n sensors, parity
    dimension df and nw window scales (``sensors`` starts at :data:`SET_SENSORS0`)."""
    o_mats = offset(_MATS, n, nw)
    return offset(_SCALES, n, nw), o_mats, o_mats + (3 * df + 3) * n


@register_jitable(inline="always")
def state_size(n: int, ring: int) -> int:
    """Entries of the float detector state of n sensors and a ring of R cumulative sums."""
    return offset(_WINDOWS, n, 0) + (ring + 1) * (n + 1)


def c_enums() -> str:
    """The tables of :data:`LAYOUT` as C enumerations (the exported module's slot names)."""
    lines = []
    for names in LAYOUT:
        lines.append(f"/* {names.title} */")
        line = "enum {"
        for k, v in names.values.items():
            item = f" {k} = {v},"
            if len(line) + len(item) > 96:
                lines.append(line)
                line = "      "
            line += item
        lines.append(line.removesuffix(",") + " };")
    return "\n".join(lines)


@dataclass(frozen=True)
class OutLayout:
    """Columns of one output row: ω̂ (3), protection level, K statistics, K thresholds and
    (optionally) the parity vector padded to n − 3."""

    K: int
    n_parity: int

    @property
    def thresholds0(self) -> int:
        """First threshold column."""
        return OUT.STATS0 + self.K

    @property
    def parity0(self) -> int:
        """First parity column."""
        return OUT.STATS0 + 2 * self.K

    def width(self, parity: bool) -> int:
        """Columns of a row with or without the parity vector."""
        return self.parity0 + (self.n_parity if parity else 0)


@dataclass(frozen=True, eq=False)
class KernelSet:
    """The constants of one healthy set in the kernel's layout (see the module docstring).

    ``packed`` is the one array the kernel reads (fewer arguments per call: numba's dispatch
    costs ~45 ns per array); the other fields are views of it, in the order of
    :data:`SET_PARTS`: ``fconst`` | ``iconst`` (as float64) | ``sensors`` | ``scales`` |
    ``mats``.
    """

    packed: np.ndarray
    sensors: np.ndarray
    scales: np.ndarray
    mats: np.ndarray
    fconst: np.ndarray
    iconst: np.ndarray


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
    nw = len(thresholds.scales)
    o_scales, o_mats, end = set_layout(n, df, nw)
    packed = np.zeros(end)
    fconst = span(packed, SET_PARTS["SET_FCONST"], n, nw)
    sensors = span(packed, SET_PARTS["SET_SENSORS"], n, nw).reshape(SENSORS.SENSOR_COLS, n)
    scales = packed[o_scales:o_mats].reshape(nw, SCALES.SCALE_COLS)
    mats = packed[o_mats:end].reshape(3 * df + 3, n)
    c = SENSORS
    sensors[c.SF] = model.sf
    sensors[c.BIAS] = model.bias
    sensors[c.LO] = lo
    sensors[c.HI] = hi
    sensors[c.IN_SET, list(model.idx)] = 1.0
    sensors[c.SIGMA_II] = sigma_diag
    cov = np.nan_to_num(np.asarray(model.cov, float))
    sensors[c.H_P_H] = np.einsum("ia,ab,ib->i", H, cov, H)
    sensors[c.AXIS0:c.AXIS0 + 3] = H.T
    sensors[c.RHO_COEF0:c.RHO_COEF0 + 6] = np.asarray(model.cal_coef).T
    # the kernel's dense loops need zeros (+0.0) outside the set: ρ coefficients, V and G
    out_of_set = [i for i in range(n) if i not in model.idx]
    if model.jit_coef is not None:
        sensors[c.JITTER_COEF] = model.jit_coef
    sensors[c.RHO_COEF0:c.JITTER_COEF + 1, out_of_set] = 0.0
    s = SCALES
    scales[:, s.WINDOW] = thresholds.scales
    scales[:, s.THRESHOLD] = model.thr
    scales[:, s.CHI2_SCALE] = model.chi2_scale
    scales[:, s.RHO_GAIN] = model.rho_gain
    scales[:, s.OFFSET_GAIN] = model.offset_gain
    scales[:, s.CLEAR_THRESHOLD] = clear_thresholds(model.thr, df, settings)
    mats[:df] = model.V
    mats[df:df + 3] = model.G
    mats[df + 3:2 * df + 3, :df] = model.A
    if df:
        norms = np.linalg.norm(model.U, axis=0)
        unit = np.where(norms > 0, model.U / np.where(norms > 0, norms, 1.0), 0.0)
        mats[2 * df + 3:, list(model.idx)] = unit
        sensors[c.U_NORM2, list(model.idx)] = norms**2
    mats[:df + 3, out_of_set] = 0.0
    f = FCONST
    fconst[f.KAPPA] = model.kappa
    fconst[f.BETA] = model.beta
    fconst[f.NU] = thresholds.cusum_drift
    fconst[f.CUSUM_H] = model.cusum_h
    fconst[f.CUSUM_CLEAR] = settings.clear_ratio * model.cusum_h
    pl = model.pl
    fconst[[f.PL_A, f.PL_B, f.PL_C, f.PL_D, f.PL_E]] = pl.a, pl.b, pl.c, pl.d, pl.e
    fconst[f.STALE_TIMEOUT_S] = settings.stale_timeout_s
    fconst[f.READMIT_DWELL_S] = settings.readmit_dwell_s
    fconst[f.READMIT_GATE] = settings.readmit_gate
    fconst[f.STALE_SAMPLES] = settings.stale_timeout_s * thresholds.sample_rate_hz
    fconst[f.MAX_TIME_STEP_S] = settings.max_time_step_s
    fconst[f.NOISE_GAIN] = 1.0 / (settings.noise_window_s * thresholds.sample_rate_hz)
    fconst[f.NOISE_CLIP] = settings.noise_clip
    fconst[f.NOISE_BAND] = 1.0 + settings.noise_band
    fconst[f.NOISE_MAX] = settings.noise_scale_max
    fconst[f.VIB_RATIO] = settings.vibration_ratio
    fconst[f.VIB_LEVEL] = settings.vibration_level
    i = ICONST
    iconst = np.zeros(i.I_SLOTS, np.int64)
    iconst[i.DF] = df
    iconst[i.N_WINDOWS] = nw
    iconst[i.HAS_CUSUM] = thresholds.detector != "windows"
    iconst[i.CAPABILITY] = CAPABILITY_CODE[model.capability]
    iconst[i.HAS_OMEGA] = model.capability != "none"
    iconst[i.STUCK_COUNT] = settings.stuck_count
    iconst[i.PERSISTENCE] = settings.persistence
    iconst[i.CLEAR_SAMPLES] = settings.clear_samples
    iconst[i.READMISSION] = bool(settings.readmission)
    iconst[i.N_SENSORS] = n
    iconst[i.REBASE_SAMPLES] = settings.time_rebase_samples
    iconst[i.VIB_DWELL] = max(1, math.ceil(settings.vibration_dwell_s
                                           * thresholds.sample_rate_hz))
    # the vibration test blames one sensor only where the set can tell sensors apart
    iconst[i.VIB_ON] = (df >= 2 and model.capability == "isolate"
                        and settings.vibration_ratio > 0)
    # persistent alarms go to the monitor's isolation test wherever it can tell hypotheses
    # apart at all (df ≥ 2): a set that isolates may exclude, one that only detects narrows
    # its suspects (fdi.monitor)
    iconst[i.ASK_ISOLATE] = df >= 2 and model.capability in ("isolate", "detect")
    span(packed, SET_PARTS["SET_ICONST"], n, nw)[:] = iconst
    return KernelSet(packed, sensors, scales, mats, fconst, iconst)


class DetectorState:
    """Mutable state of the recursion (see the module docstring for the layout).

    The float state is one array, ``values`` (the kernel takes it whole); ``sensor``,
    ``cusum`` and ``windows`` are views of it, its parts in :data:`STATE_PARTS`.

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
        self.values = np.zeros(state_size(n, ring))
        part = STATE_PARTS
        self._o_windows = offset(part["STATE_WINDOWS"], n, 0)
        self.sensor = span(self.values, part["STATE_SENSOR"], n, 0).reshape(
            n, SENSOR_STATE.SENSOR_STATE_COLS)
        self.sensor[:, SENSOR_STATE.LAST_RAW] = np.nan
        self.sensor[:, SENSOR_STATE.LAST_VALID_T] = np.nan
        self.sensor[:, SENSOR_STATE.GOOD_SINCE_T] = np.nan
        self.clock = span(self.values, part["STATE_CLOCK"], n, 0)
        """The monitor's time base: last good time stamp, candidate new base (:data:`CLOCK`;
        NaN: none)."""
        self.clock[:] = np.nan
        self.noise = span(self.values, part["STATE_NOISE"], n, 0)
        """v: the running noise level of the whitened parity, 1 at the calibrated level
        (:func:`fdi.kernel.noise_update`)."""
        self.noise[:] = 1.0
        self.vibration = span(self.values, part["STATE_VIB"], n, 0)
        """v_i: the running noise level along each sensor's unit whitened parity column."""
        self.cusum = span(self.values, part["STATE_CUSUM"], n, 0).reshape(CUSUM.CUSUM_ROWS, n)
        self.omega_prev = span(self.values, part["SCRATCH_PREV"], n, 0)
        """ω̂ of the last completed sample (rad/s; NaN before the first): the jitter term's
        ω̇̂ = (ω̂_t − ω̂_{t−1})·fs (:mod:`fdi.kernel`)."""
        self.omega_prev[:] = np.nan
        span(self.values, part["SCRATCH_BEFORE"], n, 0)[:] = np.nan   # and the ω̂ before it
        self.counters = np.zeros(COUNTERS.HEALTH0 + n, np.int64)
        self.counters[COUNTERS.RING_LEN] = ring
        self.new_set(0)

    def new_set(self, df: int) -> None:
        """Empty windows, CUSUM and detection for a new healthy set of parity dimension df."""
        o = self._o_windows
        self.values[o:] = 0.0
        self.windows = self.values[o:o + (self.ring + 1) * (df + 1)].reshape(self.ring + 1,
                                                                             df + 1)
        self.cusum[:] = 0.0
        self.vibration[:] = 1.0             # the columns change with the set; v does not
        c = COUNTERS
        self.counters[[c.RING_POS, c.WINDOW_COUNT, c.DETECTED, c.DETECTED_ROWS, c.ALARM_RUN,
                       c.CLEAR_RUN, c.HOLD_OPEN, c.ZPREV_OK, c.VIB_RUN]] = 0

    @property
    def cumulative(self) -> np.ndarray:
        """Current cumulative sums c_t of (z, ρ), shape (df + 1,)."""
        return self.windows[self.ring]

    def window_sum(self, w: int) -> np.ndarray:
        """Σ z over the last ``w`` complete samples, shape (df,)."""
        pos = int(self.counters[COUNTERS.RING_POS]) - w
        old = self.windows[pos % self.ring]
        cur = self.windows[self.ring]
        return cur[:-1] - old[:-1]

    def cusum_scores(self, m_idx: tuple[int, ...]) -> np.ndarray:
        """CUSUM statistic max(S⁺ − min S⁺, S⁻ − min S⁻) per healthy sensor."""
        c = self.cusum[:, list(m_idx)]
        return np.maximum(c[CUSUM.S_UP] - c[CUSUM.MIN_UP], c[CUSUM.S_DOWN] - c[CUSUM.MIN_DOWN])
