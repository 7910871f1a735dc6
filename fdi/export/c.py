"""``rimu export c``: the monitor of one calibrated set as a self-contained C99 module.

The module is a fixed template (``templates/rimu_monitor.c.in`` and ``.h.in``, package
data) plus tables generated here from the same objects :class:`fdi.monitor.Monitor` builds:
per healthy set (every bitmask of the n sensors) the packed constants of
:func:`fdi.state.pack_set` (compensation, health bounds, ρ coefficients, window scales,
V, G, A and the unit whitened columns), the whitened parity columns U, the ω̂ standard
deviation and the χ² levels of the isolation decision (:func:`fdi.isolation.decide`:
the rejection level c and the subset threshold per scale, computed here with scipy so the C
needs no quantile function); the window lengths and variance factors; the effect terms of
:class:`fdi.effects.Compensator` with their constants folded as ``Compensator.one`` folds
them. Nothing of the per-sample arithmetic is written here: it is in the template, in the
order of :mod:`fdi.kernel` and :mod:`fdi.monitor`.

What the C cannot carry faithfully is refused with :class:`ExportError` (one line naming
it): more sensors than the tables fit (:data:`MAX_TABLE_BYTES`), a window longer than
:data:`MAX_RING` samples, and, for a float32 module, a finite table entry beyond float32's
range.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import zlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from fdi import state as S
from fdi.calfile import Calibration
from fdi.capability import AXIS_SHARE
from fdi.detector import chi2_threshold, default_thresholds
from fdi.effect_specs import RUNTIME_INPUTS
from fdi.effects import Compensator
from fdi.envelope import SATURATION
from fdi.errors import ExportError
from fdi.health import health_limits
from fdi.isolation import rejection_level
from fdi.reconstruction import SetCache
from fdi.settings import MonitorSettings, Thresholds
from fdi.units import MS

__all__ = ["ALL_SETS_UP_TO", "API_VERSION", "AUTO_TABLE_BUDGET", "DEFAULT_DEPTH", "MAX_RING",
           "MAX_SENSORS", "MAX_TABLE_BYTES", "PRECISIONS", "CModule", "generate_c",
           "reachable_sets", "write_c"]

PRECISIONS = ("float64", "float32")
API_VERSION = 2
"""``RIMU_API_VERSION`` of the generated module: 2 since ``rimu_monitor_step`` returns a
status and the module carries its identity and table CRC (1: the first modules)."""
MAX_TABLE_BYTES = 8 << 20
"""Largest set tables the export writes (8 MiB)."""
MAX_SENSORS = 31
"""Most sensors a module monitors (its healthy set is the bits of an unsigned long)."""
ALL_SETS_UP_TO = 9
"""Up to this many sensors the module carries every one of the 2^n healthy sets."""
DEFAULT_DEPTH = 2
"""Beyond :data:`ALL_SETS_UP_TO` sensors, "auto" carries the sets within this many
exclusions (:func:`reachable_sets`), or fewer where their tables would
pass :data:`AUTO_TABLE_BUDGET` (1 at least)."""
AUTO_TABLE_BUDGET = 224 << 10
"""Bytes of tables "auto" allows beyond :data:`ALL_SETS_UP_TO` sensors (224 KiB: with the
code, 10–20 KiB, a module within 256 KiB of flash)."""
MAX_RING = 1 << 16
"""Longest window (samples) the export accepts: the ring of cumulative sums is static."""
_TEMPLATE_CODES = frozenset({0, 1, 2, 3})
"""The run-time codes the template's ``EFFECT_*`` switch implements (the specs'
``runtime.code``, :mod:`fdi.effect_specs.builtin`)."""
_F32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class CModule:
    """A generated module: file name → text, and what it holds.

    Attributes
    ----------
    files : dict of str to str
        ``rimu_monitor.h``, ``rimu_monitor.c``, ``README.md`` (and ``rimu_harness.c``).
    fingerprint : str
        The calibration's :meth:`~fdi.calfile.Calibration.fingerprint`.
    n, sets : int
        Sensors and healthy-set tables carried (2^n, or fewer: :func:`reachable_sets`).
    precision : str
        ``"float64"`` or ``"float32"``.
    table_bytes, state_bytes : int
        Size of the const tables and of ``rimu_state`` (bytes, for this precision; the
        compiler's struct padding may add a few).
    ops_per_step : int
        Worst-case arithmetic operations (add, multiply, divide, square root, compare) of one
        step: health, re-admission and parity passes of one sample plus a reconstruction and
        two isolation decisions (an upper bound counted from the loops, not measured).
    applied_terms, not_applied : tuple of str
        Effect terms compensated, and those the monitor does not compensate (with why).
    identity : str
        ``RIMU_IDENTITY``: 16 hex digits over calibration, thresholds, settings, precision,
        effects, the sets carried and the API version (:func:`_identity`).
    table_crc : int
        ``RIMU_TABLE_CRC``: CRC-32 of the const tables (``rimu_monitor_table_crc``).
    masks : tuple of int
        The healthy sets carried (bitmasks, ascending).
    depth : int or None
        Exclusions beyond whole IMUs the sets cover (None: every set).
    """

    files: dict[str, str]
    fingerprint: str
    n: int
    sets: int
    precision: str
    table_bytes: int
    state_bytes: int
    ops_per_step: int
    applied_terms: tuple[str, ...] = ()
    not_applied: tuple[str, ...] = field(default=())
    identity: str = ""
    table_crc: int = 0
    masks: tuple[int, ...] = ()
    depth: int | None = None


def _template(name: str) -> str:
    return resources.files("fdi.export").joinpath("templates", name).read_text("utf-8")


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("rimu")
    except Exception:                   # not installed (a source checkout)
        return "source"


class _Numbers:
    """C literals of one precision; a float32 literal beyond float32's range is refused."""

    def __init__(self, precision: str) -> None:
        self.f32 = precision == "float32"

    def __call__(self, x: float, where: str) -> str:
        x = float(x)
        if math.isnan(x):
            return "NAN"
        if math.isinf(x):
            return "INFINITY" if x > 0 else "-INFINITY"
        if x == 0.0:
            return "-0.0" if math.copysign(1.0, x) < 0 else "0"
        if self.f32:
            if abs(x) > _F32_MAX:
                raise ExportError(f"float32 export: {where} = {x:.6g} is beyond float32's "
                                  f"range (export float64)")
            s = str(np.float32(x))
            if "." not in s and "e" not in s and "inf" not in s:
                s += ".0"
            return s + "f"
        s = repr(x)
        return s


def _f64(x: float) -> str:
    """A float64 C literal (the times, which are double in both builds)."""
    return _Numbers("float64")(x, "time constant")


def _row(vals: Any, num: _Numbers, where: str) -> str:
    return "{" + ", ".join(num(v, where) for v in np.asarray(vals, float).ravel()) + "}"


def _matrix(a: np.ndarray, num: _Numbers, where: str) -> str:
    return "{" + ", ".join(_row(r, num, where) for r in a) + "}"


def _set_tables(cal: Calibration, kind: str, thresholds: Thresholds,
                settings: MonitorSettings) -> tuple[SetCache, np.ndarray, Any]:
    """The set cache built as :class:`fdi.monitor.Monitor` builds it."""
    s = cal.kind(kind)
    md = settings.missed_detection or thresholds.missed_detection
    cin = np.array([np.asarray(c.input_error_cov, float) for c in s.sensors])
    sigma = np.asarray(s.noise_covariance, float)
    bsd = np.array([c.bias_sd for c in s.sensors], float)
    jit = np.array([c.timing_jitter for c in s.sensors], float)
    cache = SetCache(s.H, s.scale_factors, s.biases, sigma, cin, thresholds, md, bsd,
                     wrong_exclusion=settings.wrong_exclusion,
                     isolation_ratio=settings.isolation_ratio, timing_jitter=jit)
    limits = health_limits(settings, kind, s.scale_factors, s.biases)
    return cache, sigma, limits


def reachable_sets(n: int, groups: tuple[str, ...], depth: int | None) -> list[int]:
    """The healthy sets the module carries a table for, as sorted bitmasks.

    ``depth`` None: every one of the 2^n sets. Otherwise the sets reached by at most
    ``depth`` exclusions, each of one sensor (an isolation, a health verdict) or of a whole
    IMU (``groups``: the IMU of each sensor, the name before its last dot as
    ``replay.time_offsets.imu_groups`` reads it; an IMU of one sensor is no group), and
    besides them every set of whole IMUs (any number of dead IMUs) and the empty set: a
    set of m sensors rarely needs more than two exclusions, and a dead IMU goes stale as a
    whole.
    """
    full = (1 << n) - 1
    if depth is None or depth >= n:
        return list(range(1 << n))
    members: dict[str, int] = {}
    for i, g in enumerate(groups):
        if g:
            members[g] = members.get(g, 0) | (1 << i)
    whole = [m for m in members.values() if m & (m - 1)]
    units = whole + [1 << i for i in range(n)]       # what one exclusion takes out
    out: set[int] = {0, full}
    for d in range(1, depth + 1):
        for combo in itertools.combinations(units, d):
            gone = 0
            for m in combo:
                gone |= m
            out.add(full & ~gone)
    for pick in range(1 << len(whole)):
        gone = 0
        for k, m in enumerate(whole):
            if (pick >> k) & 1:
                gone |= m
        out.add(full & ~gone)
    return sorted(out)


def _plus_zero(x: np.ndarray) -> bool:
    x = np.asarray(x, float)
    return bool(np.all((x == 0) & ~np.signbit(x)))


def _packed_sets(masks: list[int], n: int, cache: SetCache, sigma: np.ndarray, limits: Any,
                 settings: MonitorSettings, thresholds: Thresholds) -> list[dict[str, Any]]:
    """Per carried set: its mask, model and :func:`fdi.state.pack_set` constants."""
    out = []
    for mask in masks:
        try:
            model = cache.get(mask)
            ks = S.pack_set(model, cache.H, np.diag(sigma), limits.lo, limits.hi, settings,
                            thresholds)
        except Exception as exc:        # a set the Python monitor could not build either
            raise ExportError(f"healthy set {mask:#x}: its model cannot be built "
                              f"({exc})") from None
        df = model.df
        mats = np.asarray(ks.mats, float).reshape(3 * df + 3, n)
        U = np.zeros((df, n))
        if df:
            U[:, list(model.idx)] = model.U
        idx = list(model.idx)
        out_ = [i for i in range(n) if i not in idx]
        # the layout the C expands: V, G and the unit columns on the set's sensors only, A
        # lower triangular; everything else +0.0 (checked: the expansion writes +0.0 there)
        if not (_plus_zero(mats[:df + 3, out_]) and _plus_zero(mats[2 * df + 3:, out_])
                and _plus_zero(U[:, out_])
                and all(_plus_zero(mats[df + 3 + j, j + 1:]) for j in range(df))):
            raise RuntimeError(f"set {mask:#x}: packed matrices outside the layout the C "
                               "template expands")
        out.append({"mask": mask, "model": model, "ks": ks, "df": df, "idx": idx,
                    "mats": mats, "U": U})
    return out


def _sensor_row_kinds(packed: list[dict[str, Any]], n: int) -> list[int]:
    """Per row of ``sensors``: 0 the same in every set (one shared row), 1 per set (n
    values), 2 per set on the set's sensors only (+0.0 elsewhere), 3 IN_SET (from the
    mask)."""
    kinds = []
    first = np.asarray(packed[0]["ks"].sensors, float)
    for r in range(S.SENSOR_COLS):
        if r == S.SENSORS.IN_SET:
            kinds.append(3)
            continue
        rows = [np.asarray(p["ks"].sensors, float)[r] for p in packed]
        if all(np.array_equal(x.view(np.int64), first[r].view(np.int64)) for x in rows):
            kinds.append(0)
        elif all(_plus_zero(x[[i for i in range(n) if i not in p["idx"]]])
                 for x, p in zip(rows, packed, strict=True)):
            kinds.append(2)
        else:
            kinds.append(1)
    return kinds


def _pool_of(p: dict[str, Any], kinds: list[int]) -> list[tuple[str, list[float]]]:
    """The pool entries of one set, labelled (the order ``expand_set`` of the template
    reads them in)."""
    ks, df, idx, mats, U = p["ks"], p["df"], p["idx"], p["mats"], p["U"]
    sens = np.asarray(ks.sensors, float)
    parts: list[tuple[str, list[float]]] = []
    rows = []
    for r, k in enumerate(kinds):
        if k == 1:
            rows.extend(sens[r].tolist())
        elif k == 2:
            rows.extend(sens[r, idx].tolist())
    parts.append(("sensors", rows))
    parts.append(("V", mats[:df, idx].ravel().tolist()))
    parts.append(("G", mats[df:df + 3, idx].ravel().tolist()))
    parts.append(("A", [v for j in range(df) for v in mats[df + 3 + j, :j + 1].tolist()]))
    parts.append(("unit", mats[2 * df + 3:, idx].ravel().tolist()))
    parts.append(("U", U[:, idx].ravel().tolist()))
    return parts


def _effect_tables(cal: Calibration, kind: str, num: _Numbers, effects: bool, crc: _Crc
                   ) -> tuple[str, int, tuple[str, ...], tuple[str, ...]]:
    """The terms ``Compensator.one`` applies when every input is available (none with
    ``effects`` False, as ``--no-effects``)."""
    s = cal.kind(kind)
    every = list(range(s.n))
    comp = Compensator(cal, kind, available={k: every for k in RUNTIME_INPUTS if k != "rate"},
                       enabled=effects)
    codes, sensors, ks, extras = [], [], [], []
    for code, _name, i, k, e in comp._scalar:
        if code not in _TEMPLATE_CODES:             # the template's switch must follow
            raise RuntimeError(f"effect {_name!r}: run-time code {code}, the C template "
                               f"knows {sorted(_TEMPLATE_CODES)}")
        codes.append(int(code))
        sensors.append(int(i))
        ks.append((float(k), f"effect term {_name} sensor {i + 1}"))
        e3 = list(e) if isinstance(e, list) else [e, 0.0, 0.0]
        extras.append(([float(v) for v in e3], f"effect term {_name} sensor {i + 1}"))
    m = len(codes)
    if not m:                                       # the arrays of one zero entry
        codes, sensors, ks, extras = [0], [0], [(0.0, "")], [([0.0, 0.0, 0.0], "")]
    text = (f"#define RIMU_N_TERMS {m}\n"
            f"static const int TERM_CODE[TERMS_DIM] = {{{', '.join(map(str, codes))}}};\n"
            f"static const int TERM_SENSOR[TERMS_DIM] = {{{', '.join(map(str, sensors))}}};\n"
            f"static const rimu_real TERM_K[TERMS_DIM] = "
            f"{{{', '.join(num(v, w) for v, w in ks)}}};\n"
            f"static const rimu_real TERM_EXTRA[TERMS_DIM][3] = "
            f"{{{', '.join(_row(e3, num, w) for e3, w in extras)}}};\n"
            f"static const rimu_real EFFECT_SF[RIMU_N] = "
            f"{_row(s.scale_factors, num, 'scale factors')};\n"
            f"static const rimu_real EFFECT_BIAS[RIMU_N] = "
            f"{_row(s.biases, num, 'biases')};\n")
    for v in codes:
        crc.i32(v)
    for v in sensors:
        crc.i32(v)
    for v, _w in ks:
        crc.real(v)
    for e3, _w in extras:
        for v in e3:
            crc.real(v)
    for v in (*s.scale_factors, *s.biases):
        crc.real(v)
    applied = tuple(f"{a.term.name} on sensor {a.term.sensor + 1} ({a.reads})"
                    for a in comp.applied)
    skipped = tuple(f"{t.term.name} on sensor {t.term.sensor + 1}: {t.reason}"
                    for t in comp.skipped)
    return text, m, applied, skipped


class _Crc:
    """CRC-32 (IEEE 802.3, zlib's) of the const tables as ``rimu_monitor_table_crc`` reads
    them: every number as its little-endian bytes (reals in the module's precision, a NaN
    as the quiet NaN 0x7fc00000 / 0x7ff8000000000000, integers as 32 or 64 bits two's
    complement), table after table in the order the template lists."""

    def __init__(self, precision: str) -> None:
        self.dtype = np.dtype("<f4") if precision == "float32" else np.dtype("<f8")
        self.value = 0

    def _feed(self, b: bytes) -> None:
        self.value = zlib.crc32(b, self.value)

    def _float(self, x: float, dtype: np.dtype) -> None:
        if math.isnan(x):
            self._feed(np.array(np.nan, dtype).tobytes())
        else:
            self._feed(np.array(x, dtype).tobytes())

    def real(self, x: float) -> None:
        self._float(float(x), self.dtype)

    def f64(self, x: float) -> None:
        self._float(float(x), np.dtype("<f8"))

    def i32(self, v: int) -> None:
        self._feed((int(v) & 0xFFFFFFFF).to_bytes(4, "little"))

    def i64(self, v: int) -> None:
        self._feed((int(v) & 0xFFFFFFFFFFFFFFFF).to_bytes(8, "little"))

    def u8(self, v: int) -> None:
        self._feed(bytes([int(v) & 0xFF]))


def _ops_per_step(n: int, df: int, nw: int, cusum: bool, terms: int) -> int:
    """Worst-case arithmetic operations of one step (see :class:`CModule`)."""
    comp = 4 * n + 2 * df * n + df * (df + 1) + 6 * n + 15 + 20 * n
    health = 8 * n
    readmit = comp + 14 * n
    windows = 2 * (df + 1) + nw * (2 * df + 10)
    cus = n * (2 * df + 12) + 4 if cusum else 0
    sequential = comp + 6 + health + readmit + windows + cus + 8
    decision = n * (5 * df + 8) + 2 * df + 10
    suspect = n * (4 * df + 12)
    return 3 * sequential + comp + 2 * decision + 2 * suspect + 6 * terms


def generate_c(cal: Calibration, thresholds: Thresholds | None = None, *, kind: str = "gyro",
               settings: MonitorSettings | None = None, precision: str = "float64",
               harness: bool = False, thresholds_note: str = "",
               effects: bool = True, depth: int | str | None = "auto") -> CModule:
    """The C99 module of the monitor of ``cal``'s ``kind`` sensors.

    Parameters
    ----------
    cal : Calibration
    thresholds : Thresholds, optional
        Default: :func:`fdi.detector.default_thresholds` (as :class:`fdi.monitor.Monitor`).
    kind : str
    settings : MonitorSettings, optional
    precision : str
        ``"float64"`` or ``"float32"`` (``rimu_real`` of the module).
    harness : bool
        Also write ``rimu_harness.c``, a host program: flight-folder samples on stdin,
        answers as CSV on stdout.
    thresholds_note : str
        Where the thresholds came from (written in the header).
    effects : bool
        Compensate the calibration's effect terms (False: none, as ``--no-effects``).
    depth : int, None or "auto"
        The healthy sets carried (:func:`reachable_sets`): None every one of the 2^n, an
        int the sets within that many exclusions (a sensor or a whole IMU each) and the sets
        of whole IMUs; "auto" (default):
        every set up to :data:`ALL_SETS_UP_TO` sensors, else the largest depth up to
        :data:`DEFAULT_DEPTH` whose tables stay within :data:`AUTO_TABLE_BUDGET` (1 at
        least).

    Raises
    ------
    ExportError
        What the C cannot carry (module docstring); ConfigError for thresholds made for
        another kind or number of sensors (as the monitor).
    """
    settings, thresholds, n = _checked(cal, thresholds, kind, settings, precision)
    s = cal.kind(kind)
    nw = len(thresholds.scales)
    ring = max(int(w) for w in thresholds.scales) + 1
    df_max = max(n - 3, 0)
    real = 4 if precision == "float32" else 8
    rec_bytes = 8 + real * (S.F_SLOTS + nw * S.SCALE_COLS + 4 + nw) + 4 * S.I_SLOTS
    groups = tuple(c.name.rpartition(".")[0] for c in s.sensors)  # the IMU: before the dot
    if depth == "auto":
        return _auto_depth(cal, thresholds, groups, rec_bytes, real, kind=kind,
                           settings=settings, precision=precision, harness=harness,
                           thresholds_note=thresholds_note, effects=effects)
    if depth is not None and (isinstance(depth, bool) or not isinstance(depth, int)
                              or depth < 0):
        raise ExportError(f"depth must be a whole number of exclusions or None, got {depth!r}")
    masks = reachable_sets(n, groups, depth)
    guess = _estimate(masks, n, rec_bytes, real)
    if guess > MAX_TABLE_BYTES:
        raise ExportError(f"{n} {kind} sensors: the tables of {len(masks)} healthy sets "
                          f"would take {guess / 2**20:.1f} MiB (at most "
                          f"{MAX_TABLE_BYTES >> 20} MiB are exported; a smaller depth "
                          f"carries fewer sets)")
    num = _Numbers(precision)
    crc = _Crc(precision)
    cache, sigma, limits = _set_tables(cal, kind, thresholds, settings)
    packed = _packed_sets(masks, n, cache, sigma, limits, settings, thresholds)
    kinds = _sensor_row_kinds(packed, n)
    full_index = masks.index((1 << n) - 1)
    records, pool_text, pool_vals = _set_records(packed, kinds, cache, thresholds, num, crc)
    shared_text = _shared_rows(packed[full_index], kinds, n, num, crc)
    effect_text, n_terms, applied, skipped = _effect_tables(cal, kind, num, effects, crc)
    time_const = (settings.stale_timeout_s, settings.readmit_dwell_s,
                  settings.stale_timeout_s * thresholds.sample_rate_hz, settings.max_time_step_s)
    for v in time_const:
        crc.f64(v)
    for w in thresholds.scales:
        crc.i64(int(w))
    for v in thresholds.variance_factor:
        crc.real(v)
    cusum = thresholds.detector != "windows"
    pool_len = max(len(pool_vals), 1)
    tables = _tables_text(effect_text, time_const, thresholds, num, kinds, shared_text,
                          full_index, pool_len, records, pool_text)
    fp = cal.fingerprint() or "none"
    identity = _identity(fp, kind, precision, effects, thresholds, settings, masks)
    values = {
        "VERSION": _version(), "CAL_NAME": _c_comment(str(getattr(cal, "name", "") or
                                                          "(unnamed)")),
        "FINGERPRINT": fp, "KIND": kind, "N": str(n), "NW": str(nw),
        "HAS_CUSUM": "1" if cusum else "0", "DF_MAX": str(df_max),
        "PARITY_LEN": str(max(df_max, 1)), "RING": str(ring), "N_SETS": str(len(masks)),
        "FLOAT32": "1" if precision == "float32" else "0",
        "THRESHOLDS_NOTE": _c_comment(thresholds_note or _describe(thresholds)),
        "ONES": ", ".join(["1"] * n), "TABLES": tables, "SLOTS": S.c_enums(),
        "COUNTERS": str(S.HEALTH0 + n), "API_VERSION": str(API_VERSION),
        "SAMPLE_RATE": _f64(float(thresholds.sample_rate_hz)),
        "IDENTITY": identity, "TABLE_CRC": f"{crc.value:#010x}",
        "MAGIC": f"{(int(identity[:8], 16) | 1):#010x}",
        "F_SLOTS": str(S.F_SLOTS), "I_SLOTS": str(S.I_SLOTS),
        "SENSOR_COLS": str(S.SENSOR_COLS), "SCALE_COLS": str(S.SCALE_COLS),
        "DEPTH": _depth_text(depth),
    }
    table_bytes = len(masks) * rec_bytes + real * pool_len + real * S.SENSOR_COLS * n
    state_bytes = _state_bytes(n, df_max, nw, ring, real)
    ops = _ops_per_step(n, df_max, nw, cusum, n_terms)
    files = {"rimu_monitor.h": _fill(_template("rimu_monitor.h.in"), values),
             "rimu_monitor.c": _fill(_template("rimu_monitor.c.in"), values)}
    readme_values = dict(values, STATE_BYTES=str(state_bytes), TABLE_BYTES=str(table_bytes),
                         OPS=str(ops), PRECISION=precision,
                         APPLIED=_bullets(applied, "none"),
                         NOT_APPLIED=_bullets(skipped, "none"),
                         TIME_OFFSETS=_offsets_note(cal),
                         SETTINGS=_settings_table(settings, thresholds),
                         SENSORS=", ".join(f"{k + 1} {c.name}"
                                           for k, c in enumerate(s.sensors)))
    files["README.md"] = _fill(_template("README.md.in"), readme_values)
    if harness:
        files["rimu_harness.c"] = _fill(_template("rimu_harness.c.in"), values)
        files["rimu_block.c"] = _fill(_template("rimu_block.c.in"), values)
    return CModule(files, fp, n, len(masks), precision, table_bytes, state_bytes, ops,
                   applied, skipped, identity=identity, table_crc=crc.value,
                   masks=tuple(masks), depth=depth)


def _checked(cal: Calibration, thresholds: Thresholds | None, kind: str,
             settings: MonitorSettings | None, precision: str
             ) -> tuple[MonitorSettings, Thresholds, int]:
    """The settings and thresholds :func:`generate_c` uses and the number of sensors, after
    refusing what the C cannot carry."""
    from fdi.errors import ConfigError

    if precision not in PRECISIONS:
        raise ExportError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    settings = settings or MonitorSettings()
    s = cal.kind(kind)
    thresholds = thresholds or default_thresholds(cal, kind=kind)
    if thresholds.kind != kind or thresholds.n != s.n:
        raise ConfigError(f"thresholds are for {thresholds.n} {thresholds.kind} sensors, the "
                          f"calibration has {s.n} {kind} sensors")
    n = s.n
    if n > MAX_SENSORS:
        raise ExportError(f"{n} {kind} sensors: the exported monitor keeps its healthy set "
                          f"as the bits of an unsigned long (at most {MAX_SENSORS} sensors)")
    ring = max(int(w) for w in thresholds.scales) + 1
    if ring - 1 > MAX_RING:
        raise ExportError(f"thresholds: a window of {ring - 1} samples; the exported monitor "
                          f"keeps a static ring of at most {MAX_RING} cumulative sums")
    return settings, thresholds, n


def _estimate(masks: list[int], n: int, rec_bytes: int, real: int) -> int:
    """An upper bound of the tables' bytes, before any model is built."""
    pool = sum(_pool_len(bin(m).count("1"), n) for m in masks)
    return len(masks) * rec_bytes + real * pool


def _auto_depth(cal: Calibration, thresholds: Thresholds, groups: tuple[str, ...],
                rec_bytes: int, real: int, **kw: Any) -> CModule:
    """``depth="auto"`` of :func:`generate_c`: every set up to :data:`ALL_SETS_UP_TO`
    sensors, else the largest depth up to :data:`DEFAULT_DEPTH` whose tables stay within
    :data:`AUTO_TABLE_BUDGET` (1 at least)."""
    n = len(groups)
    if n <= ALL_SETS_UP_TO:
        return generate_c(cal, thresholds, depth=None, **kw)
    for d in range(DEFAULT_DEPTH, 1, -1):
        if _estimate(reachable_sets(n, groups, d), n, rec_bytes, real) > MAX_TABLE_BYTES:
            continue
        mod = generate_c(cal, thresholds, depth=d, **kw)
        if mod.table_bytes <= AUTO_TABLE_BUDGET:
            return mod
    return generate_c(cal, thresholds, depth=1, **kw)


def _set_records(packed: list[dict[str, Any]], kinds: list[int], cache: Any,
                 thresholds: Thresholds, num: _Numbers, crc: _Crc
                 ) -> tuple[list[str], list[str], list[float]]:
    """The ``RIMU_SETS`` records, the ``RIMU_POOL`` lines and the pool's values of the
    packed sets (CRC updated in table order: each record, then the pool)."""
    records: list[str] = []
    pool_text: list[str] = []
    pool_vals: list[float] = []
    for p in packed:
        mask, model, ks, df = p["mask"], p["model"], p["ks"], p["df"]
        where = f"set {mask:#x}"
        c = rejection_level(df, model.m, cache.wrong_exclusion)
        sub = [chi2_threshold(a, df - 1) if df > 1 else math.inf for a in thresholds.alpha]
        fconst = np.asarray(ks.fconst, float).tolist()
        iconst = [int(v) for v in ks.iconst]
        scales = np.asarray(ks.scales, float)
        sensors_named = " ".join(str(i + 1) for i in model.idx) or "none"
        records.append(
            f"    {{ /* set {mask:#x}: sensors {sensors_named}; df {df}; "
            f"{model.capability} */\n"
            f"        {mask:#x}UL, {len(pool_vals)}UL,\n"
            f"        /* fconst */ {_row(fconst, num, where + ' fconst')},\n"
            f"        /* iconst */ {{{', '.join(map(str, iconst))}}},\n"
            f"        /* scales */ {_matrix(scales, num, where + ' scales')},\n"
            f"        /* omega_sd */ {_row(model.omega_sd, num, where + ' omega_sd')},\n"
            f"        /* rejection_level */ {num(c, where + ' rejection_level')},\n"
            f"        /* subset_threshold */ {_row(sub, num, where + ' subset_threshold')}\n"
            f"    }}")
        crc.i32(mask)
        crc.i32(len(pool_vals))
        for v in fconst:
            crc.real(v)
        for v in iconst:
            crc.i32(v)
        for v in (*scales.ravel().tolist(), *np.asarray(model.omega_sd, float).tolist(), c,
                  *sub):
            crc.real(v)
        for label, vals in _pool_of(p, kinds):
            if vals:
                pool_text.append(f"    /* set {mask:#x}: {label} */ "
                                 + ", ".join(num(v, f"{where} {label}") for v in vals))
            pool_vals.extend(vals)
    for v in pool_vals:
        crc.real(v)
    return records, pool_text, pool_vals


def _shared_rows(full: dict[str, Any], kinds: list[int], n: int, num: _Numbers,
                 crc: _Crc) -> str:
    """``SENSOR_SHARED``: the sensor rows every set shares, from the full set (CRC: the
    rows, then ``SENSOR_KIND``)."""
    shared = np.zeros((S.SENSOR_COLS, n))
    full_sens = np.asarray(full["ks"].sensors, float)
    for r, k in enumerate(kinds):
        if k == 0:
            shared[r] = full_sens[r]
    text = _matrix(shared, num, f"set {(1 << n) - 1:#x} sensors")
    for v in shared.ravel():
        crc.real(v)
    for k in kinds:
        crc.u8(k)
    return text


def _tables_text(effect_text: str, time_const: tuple[float, ...], thresholds: Thresholds,
                 num: _Numbers, kinds: list[int], shared_text: str, full_index: int,
                 pool_len: int, records: list[str], pool_text: list[str]) -> str:
    """The const tables of ``rimu_monitor.c`` (``@TABLES@``)."""
    rec_text = ",\n".join(records)
    pool_body = ",\n".join(pool_text) or "    0"
    return (f"{effect_text}"
            f"#define AXIS_SHARE {AXIS_SHARE!r}\n"
            f"#define ENV_SATURATION {SATURATION}UL  /* fdi.envelope.SATURATION */\n"
            f"static const rimu_time TIME_CONST[4] = "
            f"{{{', '.join(_f64(v) for v in time_const)}}};\n"
            f"static const long long SCALE_W[RIMU_NW] = "
            f"{{{', '.join(str(int(w)) for w in thresholds.scales)}}};\n"
            f"#define SCALE_W_MAX {max(int(w) for w in thresholds.scales)}LL\n"
            f"static const rimu_real VARIANCE_FACTOR[RIMU_NW] = "
            f"{_row(thresholds.variance_factor, num, 'variance_factor')};\n"
            f"/* per row of a set's sensors table: 0 shared (SENSOR_SHARED), 1 per set, "
            f"2 per set on its sensors only, 3 IN_SET (from the mask) */\n"
            f"static const unsigned char SENSOR_KIND[SENSOR_COLS] = "
            f"{{{', '.join(map(str, kinds))}}};\n"
            f"static const rimu_real SENSOR_SHARED[SENSOR_COLS][RIMU_N] = "
            f"{shared_text};\n"
            f"#define RIMU_FULL_SET {full_index}\n"
            f"#define RIMU_POOL_LEN {pool_len}\n"
            f"/* the healthy sets carried, by mask (ascending: a binary search finds one) */\n"
            f"static const rimu_set_rec RIMU_SETS[RIMU_N_SETS] = {{\n"
            f"{rec_text}\n}};\n"
            f"/* their matrices: per set the rows of sensors that differ between sets, V, "
            f"G, A (lower triangle), the unit whitened columns and U, on the set's "
            f"sensors */\n"
            f"static const rimu_real RIMU_POOL[RIMU_POOL_LEN] = {{\n"
            f"{pool_body}\n}};\n")


def _depth_text(depth: int | None) -> str:
    """``@DEPTH@``: which healthy sets are carried, in words."""
    if depth is None:
        return "every set"
    return (f"up to {depth} exclusion{'s' if depth != 1 else ''}, of a sensor or a whole IMU "
            f"each, and every set of whole IMUs")


def _state_bytes(n: int, df_max: int, nw: int, ring: int, real: int) -> int:
    """Bytes of one ``rimu_monitor`` state (see :class:`CModule`)."""
    set_bytes = real * (S.F_SLOTS + S.SENSOR_COLS * n + nw * S.SCALE_COLS
                        + (3 * df_max + 3) * n + max(df_max, 1) * n + 4 + nw) + 4 * S.I_SLOTS
    return (8 * 5 * n + 8 * 2
            + real * (4 * n + (ring + 1) * (df_max + 1) + 3 * n + 9 + n + 1 + 1 + 2 * n)
            + 8 * (S.HEALTH0 + n) + 8 * 4 + 3 + 8 + 4 + 4 + 4 + n + 2 * set_bytes
            + 4 * 4)


def _pool_len(m: int, n: int) -> int:
    """An upper bound of the pool entries of a set of m of n sensors (for the size check
    before any model is built): every sensor row per set, V, G, A, unit columns, U."""
    df = max(m - 3, 0)
    return S.SENSOR_COLS * n + df * m + 3 * m + df * (df + 1) // 2 + 2 * df * m


def _identity(fp: str, kind: str, precision: str, effects: bool, th: Thresholds,
              st: MonitorSettings, masks: list[int]) -> str:
    """16 hex digits of SHA-256 over what decides the module's answers: the calibration's
    fingerprint, the kind, the precision, the effect switch, every field of the thresholds
    and settings, the sets carried and the API version."""
    doc = {"api": API_VERSION, "calibration": fp, "kind": kind, "precision": precision,
           "effects": bool(effects), "thresholds": _plain(th), "settings": _plain(st),
           "sets": masks}
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _plain(obj: Any) -> Any:
    """A dataclass, array or number as JSON values (floats by repr: exact)."""
    import dataclasses

    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_plain(v) for v in obj.tolist()]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return repr(float(obj))
    return repr(obj)


def write_c(module: CModule, out: str | Path) -> list[Path]:
    """Write the module's files into the folder ``out`` (created); returns the paths."""
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in module.files.items():
        p = d / name
        p.write_text(text, encoding="utf-8")
        paths.append(p)
    return paths


def _fill(text: str, values: dict[str, str]) -> str:
    for k, v in values.items():
        text = text.replace(f"@@{k}@@", v)
    if "@@" in text:
        left = text[text.index("@@"):text.index("@@") + 40]
        raise RuntimeError(f"template placeholder left unfilled: {left!r}")
    return text


def _c_comment(s: str) -> str:
    return s.replace("*/", "* /").replace("\n", " ")


def _describe(th: Thresholds) -> str:
    return (f"{th.detector}, {len(th.scales)} scales up to {max(th.scales)} samples, "
            f"{th.false_alarms_per_hour:g} false alarms per hour at {th.sample_rate_hz:g} Hz")


def _bullets(items: tuple[str, ...], empty: str) -> str:
    return "\n".join(f"- {x}" for x in items) if items else f"- {empty}"


def _offsets_note(cal: Calibration) -> str:
    offs = cal.extras.time_offsets_s()
    if not offs:
        return "The calibration records no IMU time offsets."
    parts = ", ".join(f"{g} {v / MS:+.3f} ms" for g, v in offs.items())
    return (f"The calibration records IMU time offsets ({parts}). The module, like "
            f"`fdi.Monitor`, takes samples already on one time base: move each IMU's samples "
            f"by its offset before `rimu_monitor_step` (`rimu monitor-file` does it in its "
            f"chain).")


def _settings_table(st: MonitorSettings, th: Thresholds) -> str:
    rows = [("detector", th.detector), ("window scales (samples)",
                                        ", ".join(str(w) for w in th.scales)),
            ("sample rate the thresholds assume", f"{th.sample_rate_hz:g} Hz"),
            ("persistence", st.persistence), ("clear_ratio", st.clear_ratio),
            ("clear_samples", st.clear_samples), ("clear_miss", st.clear_miss),
            ("readmission", st.readmission),
            ("readmit_dwell_s", st.readmit_dwell_s), ("readmit_gate", st.readmit_gate),
            ("stale_timeout_s", st.stale_timeout_s),
            ("stuck_count", st.stuck_count), ("wrong_exclusion", st.wrong_exclusion)]
    return "\n".join(f"| {k} | {v} |" for k, v in rows)
