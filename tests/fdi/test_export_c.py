"""``rimu export c``: the generated C module against :class:`fdi.monitor.Monitor`, sample for
sample.

Each module is compiled with the system compiler under ``-std=c99 -Wall -Wextra -Werror
-pedantic -O2`` (once per calibration and settings per session), loaded with ctypes and run
beside the Python monitor on the monitor suite's simulated scenarios (tetrad and cone6,
every fault kind, sequential faults, bad numbers, stale and stuck sensors, missing samples,
re-admission, timing jitter, the operating envelope, effect terms): the same events at the
same samples, the same healthy sets, capabilities and unverified axes, and rates,
statistics, thresholds, parity and protection levels within 1e-12 relative (float64). The
float32 module gives the same events on the simulated scenarios and stays within the bound
docs/export-c.md states. Breaking one table entry or one branch of the generated source
makes the comparison fail. Flights 41 and 83 of ``../shared/data`` (``--slow``): in-flight
calibration, the monitoring chain's own inputs (moved samples, envelope codes) fed to both.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_isolation import flight as triad_flight
from test_isolation import triads
from test_monitor import apply_random_faults, scenario, with_jitter
from test_time_stamps import blind_spot_case, check_blind_spot

from fdi.calfile import EffectTerm
from fdi.detector import default_thresholds
from fdi.effects import Compensator
from fdi.effects_monitor import CompensatedMonitor
from fdi.errors import ConfigError, ExportError
from fdi.export import generate_c, write_c
from fdi.export.host import CMonitor, compile_module, find_compiler
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from studies.synthetic import synthetic_calibration

pytestmark = pytest.mark.skipif(find_compiler() is None,
                                reason="no C compiler (cc) on the PATH")

RTOL = 1e-12
F32_OMEGA, F32_RTOL, F32_STAT = 1e-6, 1e-4, 1e-2
"""float32 module, the bound docs/export-c.md states: ω̂ within 1e-6 of the largest rate,
thresholds and protection levels within 1e-4 relative, statistics within 1 % of the larger
of the statistic and its threshold."""
FS = 100.0


# ---------------------------------------------------------------- building modules
@pytest.fixture(scope="session")
def build(tmp_path_factory):
    """``build(cal, thresholds, settings, precision)`` → CMonitor, compiled once per key."""
    cache: dict = {}

    def make(cal, th=None, settings=None, precision="float64", tag=""):
        key = (cal.fingerprint(), repr(th), repr(settings), precision, tag)
        if key not in cache:
            d = tmp_path_factory.mktemp("cexport")
            mod = generate_c(cal, th, settings=settings, precision=precision, harness=True)
            write_c(mod, d)
            lib = compile_module(d)
            cache[key] = (CMonitor.load(d, lib, [c.name for c in cal.gyro.sensors]), d, mod)
        mon, d, mod = cache[key]
        mon.reset()
        return mon
    return make


def assert_same(res, c, rtol=RTOL, events_exact=True) -> None:
    """The C answers equal the monitor's: arrays within ``rtol`` relative (NaN and inf where
    the monitor has them), discrete fields and events exactly."""
    for name in ("omega", "omega_sd", "statistics", "thresholds", "protection_level"):
        a = np.asarray(getattr(res, name), float)
        b = np.asarray(getattr(c, name), float)
        np.testing.assert_allclose(b, a, rtol=rtol, atol=0, equal_nan=True, err_msg=name)
    if res.parity is not None:
        p = res.parity
        np.testing.assert_allclose(c.parity[:, :p.shape[1]], p, rtol=rtol, atol=0,
                                   equal_nan=True, err_msg="parity")
    np.testing.assert_array_equal(c.healthy, res.healthy, err_msg="healthy")
    assert list(c.capability) == list(res.capability), "capability"
    np.testing.assert_array_equal(c.unverified, res.unverified, err_msg="unverified")
    np.testing.assert_array_equal(c.envelope, res.envelope, err_msg="envelope")
    # (times as text: an event at a NaN time stamp, "time nonfinite", equals its twin)
    pe = [(repr(e.t), e.sensor, e.type, e.reason, e.scale, e.sensors, e.envelope)
          for e in res.events]
    ce = [(repr(e.t), e.sensor, e.type, e.reason, e.scale, e.sensors, e.envelope)
          for e in c.events]
    assert ce == pe, _first_difference(pe, ce)
    if events_exact:
        for a, b in zip(res.events, c.events, strict=True):
            for f in ("statistic", "threshold", "magnitude"):
                x = np.nan if getattr(a, f) is None else getattr(a, f)
                y = np.nan if getattr(b, f) is None else getattr(b, f)
                np.testing.assert_allclose(y, x, rtol=rtol, atol=0, equal_nan=True,
                                           err_msg=f"{a.type} at t={a.t}: {f}")


def _first_difference(pe, ce) -> str:
    for k, (a, b) in enumerate(zip(pe, ce, strict=False)):
        if a != b:
            return f"event {k}: monitor {a}, C {b}"
    return f"{len(pe)} events from the monitor, {len(ce)} from the C module"


# ---------------------------------------------------------------- the module itself
def test_module_compiles_clean_and_needs_only_libm(build, tmp_path):
    """-Werror build (the fixture's), and the object refers to no symbol but math
    functions: no heap, no stdio, no library beyond <math.h> (and the block moves GCC
    may turn copy loops into, which it requires in a freestanding build too)."""
    cal = synthetic_calibration("cone6", seed=1)
    mod = generate_c(cal)
    write_c(mod, tmp_path)
    obj = tmp_path / "m.o"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-c",
                    str(tmp_path / "rimu_monitor.c"), "-o", str(obj)], check=True)
    und = subprocess.run(["nm", "-u", str(obj)], capture_output=True, text=True,
                         check=True).stdout.split()
    names = {s for s in und if s not in ("U", "w", "v")}
    assert names <= {"sqrt", "sqrtf", "fabs", "fabsf", "memcpy", "memmove", "memset"}, names
    assert not names & {"malloc", "calloc", "realloc", "free"}
    includes = [ln.strip() for ln in mod.files["rimu_monitor.c"].splitlines()
                if ln.startswith("#include")]
    assert includes == ["#include <math.h>", '#include "rimu_monitor.h"']
    assert mod.files["rimu_monitor.c"].count(cal.fingerprint()) == 1
    assert f'#define RIMU_FINGERPRINT "{cal.fingerprint()}"' in mod.files["rimu_monitor.h"]
    mon = build(cal)
    assert mon.state_bytes > 0 and mon.table_bytes >= mod.table_bytes * 0.9
    assert mon.fingerprint == cal.fingerprint()


# ---------------------------------------------------------------- the scenarios
@dataclasses.dataclass
class Case:
    """One scenario: the monitor's inputs, and what the Python monitor must show on it (so
    that the comparison is known to cover it)."""

    cal: object
    t: np.ndarray
    raw: np.ndarray
    valid: np.ndarray | None = None
    th: object = None
    settings: MonitorSettings | None = None
    envelope: np.ndarray | None = None
    force: np.ndarray | None = None
    temperature: np.ndarray | None = None
    expect: tuple = ()

    def python(self):
        mon = Monitor(self.cal, self.th, settings=self.settings)
        kw = dict(parity=True, envelope=self.envelope)
        if self.force is not None or self.temperature is not None:
            every = list(range(self.cal.gyro.n))
            comp = Compensator(self.cal, available={"specific_force": every,
                                                    "temperature": every})
            return CompensatedMonitor(mon, comp).run(self.t, self.raw, self.valid,
                                                     force=self.force,
                                                     temperature=self.temperature, **kw)
        return mon.run(self.t, self.raw, self.valid, **kw)

    def c(self, build, precision="float64"):
        return build(self.cal, self.th, self.settings, precision).run(
            self.t, self.raw, self.valid, force=self.force, temperature=self.temperature,
            envelope=self.envelope)


def faults_case(cfg, detector, N=3000):
    """Steps on three sensors (one on the tetrad), missing samples, a stuck sensor."""
    faults = [(3, 700, 8.0), (5, 1400, -10.0), (1, 2100, 12.0)] if cfg == "cone6" else \
        [(2, N - 2300, 9.0)]
    cal, t, raw, _ = scenario(cfg, N, faults, seed=4)
    valid = np.ones(raw.shape, bool)
    valid[300, 1] = False
    valid[900:903, 3] = False
    col = 5 if cfg == "cone6" else 3
    raw[N - 500:, col] = raw[N - 500, col]                  # stuck
    return Case(cal, t, raw, valid, th=default_thresholds(cal, detector=detector),
                expect=("detected", "stuck"))


def sequential_case():
    """cone6 isolates three faulty sensors down to reconstruction, then one dies."""
    cal, t, raw, _ = scenario("cone6", 4000, [(3, 500, 15.0), (5, 1500, -15.0),
                                              (1, 2500, 15.0)], seed=11)
    raw[3200:, 0] = np.nan
    return Case(cal, t, raw, expect=("isolated", "nonfinite", "reconstruct"))


BAD = [np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, 5e-324, 1e20]


def bad_numbers_case(seed):
    """Bad cells and columns, stuck values, NaN, backward, repeated and jumping times (stale
    sensors), missing samples: as the fuzz suite makes them, from fixed seeds."""
    rng = np.random.default_rng(seed)
    cal, t, raw, _ = scenario(("cone6", "tetrad")[seed % 2], 600, [], seed=seed)
    n = raw.shape[1]
    valid = np.ones(raw.shape, bool)
    for _ in range(6):
        kind = rng.choice(["cell", "column", "stuck", "tnan", "tback", "tjump", "miss",
                           "tdup"])
        row, col = int(rng.integers(0, 600)), int(rng.integers(0, n))
        if kind == "cell":
            raw[row, col] = BAD[int(rng.integers(len(BAD)))]
        elif kind == "column":
            raw[row:, col] = BAD[int(rng.integers(len(BAD)))]
        elif kind == "stuck":
            raw[row:, col] = raw[row, col]
        elif kind == "tnan":
            t[row] = np.nan
        elif kind == "tback":
            t[row:] -= rng.uniform(0, 10)
        elif kind == "tjump":
            t[row:] += [0.5, 1.0, 100.0, np.inf][int(rng.integers(4))]
        elif kind == "tdup":
            t[row:] = t[row]
        else:
            valid[row:row + int(rng.integers(1, 50)), col] = False
    return Case(cal, t, raw, valid)


def random_faults_case(seed):
    """Steps, NaN, missing runs, stuck values and spikes at random rows and sensors (the
    monitor suite's random scenarios), half of them with timing jitter."""
    rng = np.random.default_rng(100 + seed)
    cal, t, raw, _ = scenario("cone6", 800, [], seed=seed)
    if seed % 2:
        cal = with_jitter(cal, 3)                       # one jittered calibration: one build
    faults = []
    for _ in range(int(rng.integers(1, 5))):
        i, row = int(rng.integers(0, 6)), int(rng.integers(0, 700))
        size = rng.uniform(-30, 30)
        faults.append((i + 1, row, size, str(rng.choice(["step", "nan", "miss", "stuck",
                                                          "spike"]))))
    valid = apply_random_faults(cal, raw, faults)
    return Case(cal, t, raw, valid,
                th=default_thresholds(cal, detector=("windows", "both")[seed % 2]))


def readmission_case():
    cal, t, raw, _ = scenario("cone6", 1500, [(5, 1200, 12.0)], seed=8)
    raw[100:105, 1] = np.nan
    valid = np.ones(raw.shape, bool)
    valid[700:703, 3] = False
    return Case(cal, t, raw, valid,
                settings=MonitorSettings(readmission=True, readmit_dwell_s=3.0),
                expect=("readmitted", "isolated"))


def envelope_case(tmp):
    """Two IMUs on one board (detect, never isolate: 'disagree' events, unverified axes),
    a fault during and after envelope excursions of several codes."""
    cal = triads(tmp, 2, seed=2)
    sd = cal.gyro.noise_sd[0]
    t, raw = triad_flight(cal, 1500, [(2, 300, 20 * sd)], seed=5)
    env = np.zeros(1500, np.int64)
    env[250:500] = 1
    env[480:520] = 6
    env[900:950] = 8
    env[1000:1010] = 70000                      # beyond 2^16: counts as inside
    return Case(cal, t, raw, envelope=env, expect=("envelope", "detected", "disagree"))


def _effect_cal():
    cal = synthetic_calibration("tetrad", seed=1)
    terms = (EffectTerm("scale_asymmetry", "gyro", 0, 5e-3, 1e-5, "fraction", ()),
             EffectTerm("scale_nonlinearity", "gyro", 1, -2e-3, 1e-5, "fraction", (),
                        {"table_rate_dps": 100.0}),
             EffectTerm("g_sensitivity", "gyro", 2, 300.0, 1.0, "deg/h per g", ()),
             EffectTerm("temperature", "gyro", 3, 0.7, 0.01, "deg/h per degC", (),
                        {"reference_degC": 25.0}),
             EffectTerm("scale_asymmetry", "gyro", 3, -1e-3, 1e-5, "fraction", ()),
             EffectTerm("bias_step", "gyro", 0, 3.0, 0.1, "deg/h", (), {"time_s": 10.0}))
    return dataclasses.replace(cal, effects=terms)


def effects_case():
    """Every compensable effect, with specific force and temperature inputs (NaN now and
    then: the term adds 0), as CompensatedMonitor applies them."""
    cal = _effect_cal()
    N = 1500
    _, t, raw, _ = scenario("tetrad", N, [(2, 900, 12.0)], seed=3)
    rng = np.random.default_rng(3)
    force = np.column_stack([rng.normal(0, 2, N), rng.normal(0, 2, N), rng.normal(9.8, 3, N)])
    force[100:110] = np.nan
    temp = 25 + 10 * rng.random((N, 4))
    temp[200:205, 3] = np.nan
    return Case(cal, t, raw, force=force, temperature=temp, expect=("detected",))


def vibration_case(tmp):
    """Three IMUs, imu3.z at 3x its noise from 5 s: the noise scale follows, the vibration
    test excludes it (status and reason ``vibration``)."""
    from replay.faults import parse_fault
    from replay.flight_sim import simulate_flight

    cal = triads(tmp, 3, seed=2)
    fl = simulate_flight(cal, 20.0, seed=3, faults=[parse_fault("noise:9:3x:5", cal)],
                         max_rate_dps=100.0)
    return Case(cal, fl.t, fl.raw, expect=("vibration",))


CASES = {
    **{f"{cfg}-{det}": (lambda tmp, cfg=cfg, det=det: faults_case(cfg, det))
       for cfg in ("cone6", "tetrad") for det in ("windows", "both", "cusum")},
    "tetrad-10-min": lambda tmp: faults_case("tetrad", "both", 60000),
    "sequential": lambda tmp: sequential_case(),
    **{f"bad-numbers-{k}": (lambda tmp, k=k: bad_numbers_case(k)) for k in range(6)},
    **{f"random-faults-{k}": (lambda tmp, k=k: random_faults_case(k)) for k in range(8)},
    "readmission": lambda tmp: readmission_case(),
    "envelope-two-imus": envelope_case,
    "vibration-three-imus": vibration_case,
    "effects": lambda tmp: effects_case(),
}
F32_CASES = ["cone6-both", "tetrad-10-min", "sequential", "bad-numbers-0", "bad-numbers-3",
             "random-faults-0", "random-faults-1", "readmission", "envelope-two-imus",
             "effects"]


def _check_expected(case, res) -> None:
    seen = {e.type for e in res.events} | {e.reason for e in res.events} | set(res.capability)
    assert set(case.expect) <= seen, (case.expect, seen)


# ---------------------------------------------------------------- float64: sample for sample
@pytest.mark.parametrize("name", list(CASES))
def test_same_answers_as_the_monitor(build, tmp_path, name):
    case = CASES[name](tmp_path)
    res = case.python()
    _check_expected(case, res)
    assert_same(res, case.c(build))


def test_same_answers_with_a_rate_error_factor(build, tmp_path):
    """``Thresholds.rate_error_factor`` q > 1 (``rimu tune``'s per-calibration term) reaches
    the C module: its answers equal the monitor's, and q changes what the monitor gives (so
    the comparison covers it)."""
    case = faults_case("cone6", "both")
    q_th = dataclasses.replace(case.th, rate_error_factor=2.18)
    base = case.python()
    case = dataclasses.replace(case, th=q_th)
    res = case.python()
    assert not np.allclose(res.protection_level, base.protection_level, equal_nan=True), \
        "q = 2.18 left the protection level unchanged: the case does not cover it"
    assert_same(res, build(case.cal, q_th).run(case.t, case.raw, case.valid))


@pytest.mark.parametrize("bad", ["inf", "1e300", "backward-reset", "frozen"])
def test_no_blind_spot_from_a_bad_time_stamp(build, bad):
    """Issue 28's must-hold in C: a bad time stamp, a sensor silent later, a step on another
    later still: the C module gives the monitor's answers, and they hold it."""
    cal, t, raw, valid = blind_spot_case(bad)
    res = Monitor(cal).run(t, raw, valid, parity=True)
    c = build(cal).run(t, raw, valid)
    assert_same(res, c)
    check_blind_spot(c)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cfg=st.sampled_from(["cone6", "tetrad"]), seed=st.integers(0, 10_000),
       edits=st.lists(st.tuples(st.sampled_from(["step", "cell", "column", "stuck", "miss",
                                                 "tback", "tjump", "spike"]),
                                st.integers(0, 399), st.integers(0, 5), st.floats(-40, 40)),
                      max_size=5))
def test_same_answers_on_drawn_scenarios(build, cfg, seed, edits):
    """Faults, bad numbers and bad times drawn by hypothesis on the two default modules."""
    cal, t, raw, _ = scenario(cfg, 400, [], seed=seed % 50)
    n = raw.shape[1]
    valid = np.ones(raw.shape, bool)
    sd = cal.gyro.noise_sd / cal.gyro.scale_factors
    for kind, row, col, x in edits:
        col %= n
        if kind == "step":
            raw[row:, col] += x * sd[col]
        elif kind == "cell":
            raw[row, col] = BAD[int(abs(x)) % len(BAD)]
        elif kind == "column":
            raw[row:, col] = BAD[int(abs(x)) % len(BAD)]
        elif kind == "stuck":
            raw[row:, col] = raw[row, col]
        elif kind == "miss":
            valid[row:row + int(abs(x)) + 1, col] = False
        elif kind == "tback":
            t[row:] -= abs(x) / 10
        elif kind == "tjump":
            t[row:] += abs(x) / 20
        else:
            raw[row, col] += 50 * x * sd[col]
    case = Case(cal, t, raw, valid)
    assert_same(case.python(), case.c(build))


def test_same_status_and_suspects_as_step(build, tmp_path):
    """The fields only the stepped answer carries: per-sensor status and the suspects."""
    cal = triads(tmp_path, 2, seed=2)
    sd = cal.gyro.noise_sd[0]
    t, raw = triad_flight(cal, 600, [(4, 200, 25 * sd)], seed=7)
    raw[450:, 0] = np.inf
    mon = Monitor(cal)
    answers = [mon.step(t[r], raw[r]) for r in range(600)]
    c = build(cal).run(t, raw)
    status = [tuple(a.status) for a in answers]
    assert [tuple(s) for s in c.status] == status
    sus = [sum(1 << (i - 1) for i in a.suspects) for a in answers]
    assert [int(s) for s in c.suspects] == sus
    assert any("detected" in s for s in status) and any(sus)


def test_same_answers_for_an_accelerometer_set(tmp_path):
    """``kind="accel"``: the accelerometers' measuring range in the health bounds, the
    accelerometer thresholds; a step and an out-of-range value."""
    cal, t, raw, _ = scenario("cone6", 1500, [(4, 600, 12.0)], seed=6)
    acc = dataclasses.replace(cal.gyro, kind="accel")
    cal = dataclasses.replace(cal, sets={"accel": acc})
    raw[1100, 2] = 170.0 / acc.scale_factors[2]                # beyond 160 m/s²
    th = default_thresholds(cal, kind="accel")
    write_c(generate_c(cal, th, kind="accel", harness=True), tmp_path)
    c = CMonitor.load(tmp_path, compile_module(tmp_path), [s.name for s in acc.sensors])
    res = Monitor(cal, th, kind="accel").run(t, raw, parity=True)
    assert {"isolated", "range"} <= {e.type for e in res.events} | {e.reason
                                                                    for e in res.events}
    assert_same(res, c.run(t, raw))


def test_effect_terms_the_monitor_does_not_apply_are_listed():
    mod = generate_c(_effect_cal())
    assert len(mod.applied_terms) == 5
    assert [s.split(":")[0] for s in mod.not_applied] == ["bias_step on sensor 1"]
    assert "bias_step on sensor 1: session-specific" in mod.files["README.md"]
    off = generate_c(_effect_cal(), effects=False)        # --no-effects
    assert off.applied_terms == () and len(off.not_applied) == 6
    assert "#define RIMU_N_TERMS 0" in off.files["rimu_monitor.c"]


@pytest.mark.slow
def test_same_answers_three_imus(build, tmp_path):
    """Three IMUs on one board (9 sensors, 512 set tables, a 2.5 MB source): a verified
    exclusion of the first fault, then a second fault the remaining set cannot attribute."""
    cal = triads(tmp_path, 3, seed=2)
    sd = cal.gyro.noise_sd[0]
    t, raw = triad_flight(cal, 2000, [(1, 500, 20 * sd), (5, 1200, -25 * sd)], seed=5)
    case = Case(cal, t, raw, expect=("isolated", "disagree"))
    res = case.python()
    _check_expected(case, res)
    assert_same(res, case.c(build))


# ---------------------------------------------------------------- float32
F32_RANGE = float(np.finfo(np.float32).max)


def assert_float32_within_the_bound(res, c) -> None:
    """The float32 module against the float64 monitor (docs/export-c.md): the same events
    at the same samples (a raw value beyond float32's range is ±inf once it is a float:
    'nonfinite' where the monitor says 'range'), the same healthy sets, capabilities,
    unverified axes and envelope codes; ω̂ within F32_OMEGA of the largest rate, thresholds
    and protection levels within F32_RTOL relative, statistics within F32_STAT of the larger
    of the statistic and its threshold."""

    def key(e, f32):
        reason = e.reason
        if not f32 and reason == "range" and abs(e.statistic) > F32_RANGE:
            reason = "nonfinite"
        return (repr(e.t), e.sensor, e.type, reason, e.scale, e.sensors, e.envelope)

    pe = [key(e, False) for e in res.events]
    ce = [key(e, True) for e in c.events]
    assert ce == pe, _first_difference(pe, ce)
    np.testing.assert_array_equal(c.healthy, res.healthy)
    assert list(c.capability) == list(res.capability)
    np.testing.assert_array_equal(c.unverified, res.unverified)
    np.testing.assert_array_equal(c.envelope, res.envelope)
    for name in ("omega", "statistics", "thresholds", "protection_level"):
        a = np.asarray(getattr(res, name), float)
        b = np.asarray(getattr(c, name), float)
        np.testing.assert_array_equal(np.isnan(b), np.isnan(a), err_msg=name)
        np.testing.assert_array_equal(np.isinf(b), np.isinf(a), err_msg=name)
        ok = np.isfinite(a)
        if not ok.any():
            continue
        if name == "omega":
            err = np.max(np.abs(b[ok] - a[ok])) / np.max(np.abs(a[ok]))
            bound = F32_OMEGA
        elif name == "statistics":
            err = np.max(np.abs(b[ok] - a[ok]) / np.maximum(res.thresholds[ok], a[ok]))
            bound = F32_STAT
        else:
            err = np.max(np.abs(b[ok] - a[ok]) / np.abs(a[ok]))
            bound = F32_RTOL
        assert err < bound, (name, err)


@pytest.mark.parametrize("name", F32_CASES)
def test_float32_same_events_within_the_bound(build, tmp_path, name):
    """The float32 module on the simulated scenarios (among them 10 min of a tetrad at
    100 Hz: the bound does not grow with the run)."""
    case = CASES[name](tmp_path)
    res = case.python()
    c = case.c(build, "float32")
    assert_float32_within_the_bound(res, c)
    assert not np.array_equal(c.omega, res.omega, equal_nan=True)     # it is float32


# ---------------------------------------------------------------- mutations are caught
MUTATIONS = {
    # one branch: isolate one sample later than the monitor
    "persistence branch": ("if (ask_isolate && c[ALARM_RUN] >= persistence) {",
                           "if (ask_isolate && c[ALARM_RUN] > persistence) {"),
    # one branch: a window is tested one sample after it is full
    "window full": ("if (count >= w) {", "if (count > w) {"),
    # one branch: the stuck count
    "stuck branch": ("if (sen[SAME_RUN] >= (rimu_time)stuck) {",
                     "if (sen[SAME_RUN] > (rimu_time)stuck) {"),
}


TABLE_MUTATIONS = {
    # (label of a table entry of the full set, factor): see fdi.export.c.generate_c
    "table entry V": ("V", 1 + 1e-9),            # the first entry of the parity matrix V
    "table entry c": ("rejection_level", 2.0),   # the isolation decision's rejection level
}


def _mutate_table(text: str, label: str, factor: float) -> str:
    """The first non-zero number after ``label`` in the full set's tables, times
    ``factor`` (V lives in the pool, the rejection level in the set's record)."""
    import re

    if label == "V":
        start = text.index("/* set 0x3f: V */") + len("/* set 0x3f: V */")
    else:
        start = text.index(f"/* {label} */", text.index("/* set 0x3f: sensors"))
        start += len(f"/* {label} */")
    end = text.index("\n", start)
    for m in re.finditer(r"-?(?:\d+\.\d*|\d+)(?:e[+-]?\d+)?", text[start:end]):
        v = float(m.group())
        if v != 0:
            a, b = start + m.start(), start + m.end()
            return text[:a] + repr(v * factor) + text[b:]
    raise AssertionError("no number to mutate")


@pytest.mark.parametrize("mutation", [*MUTATIONS, *TABLE_MUTATIONS])
def test_a_broken_entry_or_branch_is_caught(build, tmp_path, mutation):
    cal, t, raw, _ = scenario("cone6", 3000, [(3, 700, 8.0), (5, 1400, -10.0),
                                              (1, 2100, 12.0)], seed=4)
    raw[2500:, 5] = raw[2500, 5]                        # stuck (the counter's verdict)
    mod = generate_c(cal, harness=True)
    write_c(mod, tmp_path)
    src = tmp_path / "rimu_monitor.c"
    text = src.read_text()
    if mutation in TABLE_MUTATIONS:
        new = _mutate_table(text, *TABLE_MUTATIONS[mutation])
    else:
        old, repl = MUTATIONS[mutation]
        assert text.count(old) == 1, mutation
        new = text.replace(old, repl)
    assert new != text
    res = Monitor(cal).run(t, raw, parity=True)
    assert any(e.reason == "stuck" for e in res.events)
    names = [c.name for c in cal.gyro.sensors]
    assert_same(res, build(cal).run(t, raw))           # the intact module passes
    src.write_text(new)
    bad = CMonitor.load(tmp_path, compile_module(tmp_path, tmp_path / "bad.so"), names)
    with pytest.raises(AssertionError):
        assert_same(res, bad.run(t, raw))


# ---------------------------------------------------------------- refusals
def test_refuses_what_it_cannot_carry(monkeypatch):
    import fdi.export.c as export_c

    cal = synthetic_calibration("tetrad", seed=1)
    th = default_thresholds(cal)
    long = dataclasses.replace(th, scales=(*th.scales[:-1], 1 << 17))
    with pytest.raises(ExportError, match="window of 131072 samples"):
        generate_c(cal, long)
    g = cal.gyro
    tiny = dataclasses.replace(g, sensors=tuple(dataclasses.replace(s, scale_factor=1e-40)
                                                if k == 2 else s
                                                for k, s in enumerate(g.sensors)))
    big = dataclasses.replace(cal, sets=dict(cal.sets, gyro=tiny))
    generate_c(big)                                     # float64 carries it
    with pytest.raises(ExportError, match=r"float32 export: set 0x[0-9a-f]+ sensors = .* "
                                          "beyond float32's range"):
        generate_c(big, precision="float32")
    with pytest.raises(ConfigError, match="thresholds are for 6"):
        generate_c(cal, default_thresholds(synthetic_calibration("cone6", seed=1)))
    monkeypatch.setattr(export_c, "MAX_TABLE_BYTES", 2_000)
    with pytest.raises(ExportError, match=r"4 gyro sensors: the tables of 16 healthy sets "
                                          r"would take 0\.0 MiB"):
        generate_c(cal)


# ---------------------------------------------------------------- the command and the harness
def test_cli_exports_and_the_harness_runs_a_flight_folder(tmp_path, capsys):
    """``rimu export c --harness``: the files, the sizes printed; the harness program reads
    a flight folder's samples.csv on stdin and gives the monitor's events at the monitor's
    samples."""
    from replay.flight import save_flight_dir, simulate_flight
    from rimu.cli import main

    cal = synthetic_calibration("cone6", seed=1)
    calf = tmp_path / "cal.json"
    cal.save(calf)
    fl = simulate_flight(cal, 20.0, seed=3)
    raw = fl.raw.copy()
    sd = cal.gyro.noise_sd / cal.gyro.scale_factors
    raw[700:, 2] += 12 * sd[2]
    raw[1500:, 4] = np.nan
    fl = dataclasses.replace(fl, raw=raw)
    save_flight_dir(fl, tmp_path / "flight")
    out = tmp_path / "mod"
    assert main(["export", "c", "--cal", str(calf), "--out", str(out), "--harness"]) == 0
    said = capsys.readouterr().out
    assert cal.fingerprint() in said and "state" in said and "per step" in said
    assert {p.name for p in out.iterdir()} == {"rimu_monitor.h", "rimu_monitor.c",
                                               "README.md", "rimu_harness.c", "rimu_block.c"}
    exe = tmp_path / "harness"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2",
                    str(out / "rimu_harness.c"), str(out / "rimu_monitor.c"), "-lm", "-o",
                    str(exe)], check=True)
    with open(tmp_path / "flight" / "samples.csv", "rb") as f:
        csv = subprocess.run([str(exe)], stdin=f, capture_output=True, check=True).stdout
    lines = csv.decode().splitlines()
    assert lines[0].startswith("t,omega_x") and len(lines) == len(fl.t) + 1
    got = [(float(ln.split(",")[0]), ev.split(":")[0], int(ev.split(":")[1]) or None)
           for ln in lines[1:] for ev in ln.split(",")[-1].split(";") if ev]
    res = Monitor(cal).run(fl.t, fl.raw, fl.valid)
    want = [(e.t, e.type, e.sensor) for e in res.events]
    assert got == want and any(w[1] == "isolated" for w in want), (got, want)
    # the diff a user makes: rimu monitor-file on the same folder, the samples as they are
    rep = tmp_path / "report.json"
    assert main(["monitor-file", str(tmp_path / "flight"), "--cal", str(calf),
                 "--no-time-offsets", "--no-envelope", "--no-effects", "--report",
                 str(rep)]) == 0
    said = [(e["t"], e["type"], e["sensor"]) for e in json.loads(rep.read_text())["events"]]
    assert said == got
    omega = np.array([[float(x) for x in ln.split(",")[1:4]] for ln in lines[1:]])
    np.testing.assert_allclose(omega, res.omega, rtol=RTOL, atol=0, equal_nan=True)


def test_cli_refuses_in_one_line_and_writes_nothing(tmp_path, capsys):
    from rimu.cli import main

    cal = synthetic_calibration("tetrad", seed=1)
    calf = tmp_path / "cal.json"
    cal.save(calf)
    th = default_thresholds(cal)
    long = dataclasses.replace(th, scales=(*th.scales[:-1], 1 << 17))
    thf = tmp_path / "long.json"
    long.save(thf)
    out = tmp_path / "mod"
    assert main(["export", "c", "--cal", str(calf), "--thresholds", str(thf), "--out",
                 str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "window of 131072 samples" in err[0], err
    assert not out.exists()


# ---------------------------------------------------------------- measured flights
ERLE = {"41": "pxf_copter_22-12-2014_41.BIN", "83": "pxf_copter_31-3-2015_83.BIN"}


@pytest.mark.slow
@pytest.mark.parametrize("inject", [False, True], ids=["as flown", "with a fault"])
@pytest.mark.parametrize("name", sorted(ERLE))
def test_same_answers_on_erle_flights(build, name, inject):
    """Flights 41 and 83 as ``rimu monitor-file`` runs them (in-flight calibration, the
    IMUs moved by their time offsets, the envelope decided by the chain's tracker): the
    inputs the chain gives the monitor go to the C module too; as flown, and with a
    0.2 rad/s step on the second gyro from mid-flight (detected; the two IMUs cannot tell
    which sensor: 'disagree')."""
    import os
    from pathlib import Path

    data = Path(os.environ.get("RIMU_SHARED_DATA",
                               Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
    path = data / "erle_pxf_dual_imu" / ERLE[name]
    if not path.exists():
        pytest.skip(f"{path} not found (set RIMU_SHARED_DATA)")
    from replay.chain import ChainOptions, chain_for_flight
    from studies.field import inflight_calibration, load_erle

    flight = load_erle(path)
    cal = inflight_calibration(flight)
    th = default_thresholds(cal)
    if inject:
        raw = flight.raw.copy()
        raw[len(raw) // 2:, 1] += 0.2 / cal.gyro.scale_factors[1]
        flight = dataclasses.replace(flight, raw=raw)
    chain = chain_for_flight(flight, cal, ChainOptions(thresholds=th, report=False))
    calls = []
    monitor_run = chain.monitor.run

    def recorded(t, raw, valid=None, **kw):
        res = monitor_run(t, raw, valid, **kw)
        calls.append((np.array(t), np.array(raw), None if valid is None else np.array(valid),
                      dict(kw), res))
        return res

    chain.monitor.run = recorded
    chain.feed_whole(flight)
    assert calls and sum(len(c[0]) for c in calls) == len(flight.t)
    cmod = build(cal, th)
    envelope_seen = False
    for t, raw, valid, kw, res in calls:
        c = cmod.run(t, raw, valid, force=kw.get("force"), temperature=kw.get("temperature"),
                     envelope=kw.get("envelope"))
        assert_same(res, c)
        envelope_seen |= bool(np.any(res.envelope))
    assert envelope_seen                      # the envelope path is exercised
    types = {e.type for c in calls for e in c[4].events}
    assert ({"detected", "disagree"} <= types) == inject, types


@pytest.mark.parametrize("gate", [9.0, 100.0])
def test_readmit_gate_follows_the_setting(build, gate):
    """The re-admission gate is a table constant of the module (fconst[READMIT_GATE]): with a
    wide gate the biased sensor of test_monitor's gate case is re-admitted, with the
    default it is not, and the C decides as the monitor does either way."""
    from test_monitor import gate_case

    cal, t, raw = gate_case()
    case = Case(cal, t, raw, settings=MonitorSettings(readmission=True, readmit_dwell_s=3.0,
                                                      readmit_gate=gate))
    res = case.python()
    assert any(e.type == "readmitted" for e in res.events) == (gate > 9.0)
    assert_same(res, case.c(build))
