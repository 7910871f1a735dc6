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

import math
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

__all__ = ["MAX_RING", "MAX_TABLE_BYTES", "PRECISIONS", "CModule", "generate_c", "write_c"]

PRECISIONS = ("float64", "float32")
MAX_TABLE_BYTES = 8 << 20
"""Largest set tables the export writes (8 MiB: 9 sensors take about 2 MiB in float64)."""
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
        Sensors and set tables (2^n).
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


def _set_initializer(mask: int, n: int, df_max: int, cache: SetCache, sigma: np.ndarray,
                     limits: Any, settings: MonitorSettings, thresholds: Thresholds,
                     num: _Numbers) -> str:
    try:
        model = cache.get(mask)
        ks = S.pack_set(model, cache.H, np.diag(sigma), limits.lo, limits.hi, settings,
                        thresholds)
    except Exception as exc:            # a set the Python monitor could not build either
        raise ExportError(f"healthy set {mask:#x}: its model cannot be built ({exc})") from None
    df = model.df
    where = f"set {mask:#x}"
    mats = np.zeros((3 * df_max + 3, n))
    mats[:3 * df + 3] = ks.mats
    U = np.zeros((max(df_max, 1), n))
    if df:
        U[:df, list(model.idx)] = model.U
    c = rejection_level(df, model.m, cache.wrong_exclusion)
    sub = [chi2_threshold(a, df - 1) if df > 1 else math.inf for a in thresholds.alpha]
    iconst = "{" + ", ".join(str(int(v)) for v in ks.iconst) + "}"
    names = " ".join(str(i + 1) for i in model.idx) or "none"
    return (f"    {{ /* set {mask:#x}: sensors {names}; df {df}; {model.capability} */\n"
            f"        {_row(ks.fconst, num, where + ' fconst')},\n"
            f"        {iconst},\n"
            f"        {_matrix(ks.sensors, num, where + ' sensors')},\n"
            f"        {_matrix(ks.scales, num, where + ' scales')},\n"
            f"        {_matrix(mats, num, where + ' mats')},\n"
            f"        {_matrix(U, num, where + ' U')},\n"
            f"        {_row(model.omega_sd, num, where + ' omega_sd')},\n"
            f"        {num(c, where + ' rejection_level')},\n"
            f"        {_row(sub, num, where + ' subset_threshold')}\n"
            f"    }}")


def _effect_tables(cal: Calibration, kind: str, num: _Numbers, effects: bool
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
        codes.append(str(code))
        sensors.append(str(i))
        ks.append(num(k, f"effect term {_name} sensor {i + 1}"))
        e3 = list(e) if isinstance(e, list) else [e, 0.0, 0.0]
        extras.append(_row(e3, num, f"effect term {_name} sensor {i + 1}"))
    m = len(codes)
    pad = "0"
    text = (f"#define RIMU_N_TERMS {m}\n"
            f"static const int TERM_CODE[TERMS_DIM] = {{{', '.join(codes) or pad}}};\n"
            f"static const int TERM_SENSOR[TERMS_DIM] = {{{', '.join(sensors) or pad}}};\n"
            f"static const rimu_real TERM_K[TERMS_DIM] = {{{', '.join(ks) or pad}}};\n"
            f"static const rimu_real TERM_EXTRA[TERMS_DIM][3] = "
            f"{{{', '.join(extras) or '{0, 0, 0}'}}};\n"
            f"static const rimu_real EFFECT_SF[RIMU_N] = "
            f"{_row(s.scale_factors, num, 'scale factors')};\n"
            f"static const rimu_real EFFECT_BIAS[RIMU_N] = "
            f"{_row(s.biases, num, 'biases')};\n")
    applied = tuple(f"{a.term.name} on sensor {a.term.sensor + 1} ({a.reads})"
                    for a in comp.applied)
    skipped = tuple(f"{t.term.name} on sensor {t.term.sensor + 1}: {t.reason}"
                    for t in comp.skipped)
    return text, m, applied, skipped


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
               effects: bool = True) -> CModule:
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

    Raises
    ------
    ExportError
        What the C cannot carry (module docstring); ConfigError for thresholds made for
        another kind or number of sensors (as the monitor).
    """
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
    nw = len(thresholds.scales)
    ring = max(int(w) for w in thresholds.scales) + 1
    if ring - 1 > MAX_RING:
        raise ExportError(f"thresholds: a window of {ring - 1} samples; the exported monitor "
                          f"keeps a static ring of at most {MAX_RING} cumulative sums")
    df_max = max(n - 3, 0)
    real = 4 if precision == "float32" else 8
    per_set = (real * (S.F_SLOTS + S.SENSOR_COLS * n + nw * S.SCALE_COLS
                       + (3 * df_max + 3) * n + max(df_max, 1) * n + 4 + nw)
               + 4 * S.I_SLOTS)
    table_bytes = per_set * (1 << n)
    if table_bytes > MAX_TABLE_BYTES:
        raise ExportError(f"{n} {kind} sensors: the 2^{n} healthy-set tables would take "
                          f"{table_bytes / 2**20:.1f} MiB (at most "
                          f"{MAX_TABLE_BYTES >> 20} MiB are exported)")
    num = _Numbers(precision)
    cache, sigma, limits = _set_tables(cal, kind, thresholds, settings)
    sets = ",\n".join(_set_initializer(mask, n, df_max, cache, sigma, limits, settings,
                                       thresholds, num) for mask in range(1 << n))
    effect_text, n_terms, applied, skipped = _effect_tables(cal, kind, num, effects)
    cusum = thresholds.detector != "windows"
    tables = (f"{effect_text}"
              f"#define AXIS_SHARE {AXIS_SHARE!r}\n"
              f"#define ENV_SATURATION {SATURATION}UL  /* fdi.envelope.SATURATION */\n"
              f"static const rimu_time TIME_CONST[4] = "
              f"{{{_f64(settings.stale_timeout_s)}, {_f64(settings.readmit_dwell_s)}, "
              f"{_f64(settings.stale_timeout_s * thresholds.sample_rate_hz)}, "
              f"{_f64(settings.max_time_step_s)}}};\n"
              f"static const long long SCALE_W[RIMU_NW] = "
              f"{{{', '.join(str(int(w)) for w in thresholds.scales)}}};\n"
              f"#define SCALE_W_MAX {max(int(w) for w in thresholds.scales)}LL\n"
              f"static const rimu_real VARIANCE_FACTOR[RIMU_NW] = "
              f"{_row(thresholds.variance_factor, num, 'variance_factor')};\n"
              f"static const rimu_set RIMU_SETS[RIMU_N_SETS] = {{\n{sets}\n}};\n")
    fp = cal.fingerprint() or "none"
    values = {
        "VERSION": _version(), "CAL_NAME": _c_comment(str(getattr(cal, "name", "") or
                                                          "(unnamed)")),
        "FINGERPRINT": fp, "KIND": kind, "N": str(n), "NW": str(nw),
        "HAS_CUSUM": "1" if cusum else "0", "DF_MAX": str(df_max),
        "PARITY_LEN": str(max(df_max, 1)), "RING": str(ring), "N_SETS": str(1 << n),
        "FLOAT32": "1" if precision == "float32" else "0",
        "THRESHOLDS_NOTE": _c_comment(thresholds_note or _describe(thresholds)),
        "ONES": ", ".join(["1"] * n), "TABLES": tables, "SLOTS": S.c_enums(),
        "COUNTERS": str(S.HEALTH0 + n),
    }
    state_bytes = (8 * 5 * n + 8 * 2
                   + real * (4 * n + (ring + 1) * (df_max + 1) + 3 * n + 9 + n + 1 + 1 + 2 * n)
                   + 8 * (S.HEALTH0 + n) + 8 * 4 + 3 + 8 + 4 + 4 + 4 + n)
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
    return CModule(files, fp, n, 1 << n, precision, table_bytes, state_bytes, ops,
                   applied, skipped)


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
