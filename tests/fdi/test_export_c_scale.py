"""``rimu export c`` beyond 2^n: the healthy sets a module carries, its build guards, its
identity and table CRC, and its refusal of a state it did not set up.

The modules are compared with :class:`fdi.monitor.Monitor` as in ``test_export_c.py``
(``assert_same``: events, healthy sets and capabilities exactly, arrays within 1e-12
relative): four triads (12 sensors, tables of 112 of the 4096 sets), a 16-sensor array
(tables of 17 of 65536), and (``--slow``) the 4×MPU9250 set of ``../shared/data`` calibrated
with ``rimu calibrate static``, as recorded and with faults injected.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import os
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from test_export_c import (
    Case,
    _check_expected,
    assert_float32_within_the_bound,
    assert_same,
    build,  # noqa: F401  (the session fixture)
)
from test_isolation import flight as triad_flight
from test_isolation import triads

from fdi.detector import default_thresholds
from fdi.export import generate_c, reachable_sets, write_c
from fdi.export.host import STRICT_FLAGS, CMonitor, compile_module, find_compiler
from fdi.monitor import Monitor
from fdi.settings import MonitorSettings
from studies.synthetic import synthetic_calibration

pytestmark = pytest.mark.skipif(find_compiler() is None,
                                reason="no C compiler (cc) on the PATH")


# ---------------------------------------------------------------- which sets are carried
def test_reachable_sets_whole_imus_and_a_depth():
    """Four triads: up to ``depth`` exclusions, each a sensor or a whole IMU, and every set
    of whole IMUs; without IMUs (names without a dot) single sensors only, and the empty
    set; None: all 2^n."""
    g4 = tuple(f"imu{k}" for k in range(1, 5) for _ in range(3))
    assert len(reachable_sets(12, g4, 0)) == 16
    # 16 sets of whole IMUs; one exclusion adds the 12 sensors
    assert len(reachable_sets(12, g4, 1)) == 16 + 12
    # two: 66 pairs of sensors, 4 x 9 an IMU and a sensor of another (6 pairs of IMUs are
    # sets of whole IMUs already)
    assert len(reachable_sets(12, g4, 2)) == 16 + 12 + 66 + 36
    none = ("",) * 16
    assert len(reachable_sets(16, none, 2)) == 1 + 16 + 120 + 1
    assert reachable_sets(4, ("",) * 4, None) == list(range(16))
    s = reachable_sets(12, g4, 2)
    assert s == sorted(s) and 0 in s and 0xFFF in s
    assert 0xFFF & ~0b111 & ~(1 << 5) in s            # imu1 out and one more
    assert 0xFFF & ~0b11 & ~(1 << 5) not in s         # three sensors
    assert 0xFFF & ~0b111111111 in s                  # three IMUs


def _array16(tmp_path):
    """16 single-axis gyros on a spiral over the sphere (no IMU groups)."""
    lines = ['schema = "rimu.configuration/1"', 'name = "array16"']
    for k in range(16):
        z = 1 - 2 * (k + 0.5) / 16
        r, phi = math.sqrt(1 - z * z), k * math.pi * (3 - math.sqrt(5))
        x, y = r * math.cos(phi), r * math.sin(phi)
        lines += ["[[sensors]]", f'name = "g{k + 1}"', f"axis = [{x!r}, {y!r}, {z!r}]"]
    p = tmp_path / "array16.toml"
    p.write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return synthetic_calibration(str(p), seed=3, misalignment_rad=0.0)


def _load(tmp_path, cal, **kw):
    mod = generate_c(cal, harness=True, **kw)
    write_c(mod, tmp_path)
    names = [s.name for s in cal.gyro.sensors]
    return mod, CMonitor.load(tmp_path, compile_module(tmp_path), names)


def test_four_triads_same_answers_within_the_carried_sets(tmp_path):
    """12 sensors (refused before: 2^12 tables), two exclusions carried (130 of the 4096
    sets): a verified exclusion, then a whole IMU that stops delivering (incomplete
    samples, then stale): every set on the way is carried, and the C answers are the
    monitor's. float64 "auto" carries one exclusion (its tables of two would pass the
    budget), float32 "auto" two."""
    cal = triads(tmp_path, 4, seed=2)
    assert generate_c(cal).depth == 1 and generate_c(cal, precision="float32").depth == 2
    mod, mon = _load(tmp_path / "m", cal, depth=2)
    assert mod.sets == 130 < 4096
    sd = cal.gyro.noise_sd[0]
    t, raw = triad_flight(cal, 2000, [(1, 500, 20 * sd)], seed=5)
    valid = np.ones(raw.shape, bool)
    valid[1300:, 6:9] = False                          # imu3 goes silent
    valid[1000:1003, 3:6] = False                      # imu2 misses three samples
    case = Case(cal, t, raw, valid, expect=("isolated", "stale"))
    res = case.python()
    _check_expected(case, res)
    c = mon.run(t, raw, valid)
    assert_same(res, c)
    assert not np.any(c.status == "untabled")


def test_a_set_beyond_the_tables_keeps_its_largest_carried_subset(tmp_path):
    """Four triads carried to depth 0 (whole IMUs only): the exclusion of one sensor leaves
    a set the module has no table for; it goes on with the largest carried subset (its IMU
    out: the other two sensors ``untabled``, never re-admitted) and keeps testing."""
    cal = triads(tmp_path, 4, seed=2)
    mod, mon = _load(tmp_path / "m", cal, depth=0)
    assert mod.sets == 16
    sd = cal.gyro.noise_sd[0]
    t, raw = triad_flight(cal, 2000, [(1, 500, 20 * sd)], seed=5)
    res = Monitor(cal, settings=MonitorSettings()).run(t, raw, parity=True)
    c = mon.run(t, raw)
    iso = [e for e in res.events if e.type == "isolated"]
    assert iso and iso[0].sensor == 1
    k = int(np.searchsorted(t, iso[0].t))
    assert [e.type for e in c.events if e.type == "isolated"] == ["isolated"]
    assert list(c.status[-1, :3]) == ["isolated", "untabled", "untabled"]
    assert c.healthy[-1].tolist() == [False] * 3 + [True] * 9
    assert np.array_equal(res.healthy[:k], c.healthy[:k])       # the same until then
    after = c.statistics[k + 200:, 0]
    assert np.isfinite(after).all()                             # still testing
    assert set(c.capability[k + 1:]) == {"isolate"}


def test_a_16_sensor_array_exports_and_answers_as_the_monitor(build, tmp_path):  # noqa: F811
    cal = _array16(tmp_path)
    mod = generate_c(cal)
    assert mod.n == 16 and mod.depth == 1 and mod.sets == 18
    sd = cal.gyro.noise_sd[0]
    t, raw = triad_flight(cal, 2000, [(4, 600, 15 * sd)], seed=7)
    case = Case(cal, t, raw, expect=("isolated",))
    res = case.python()
    _check_expected(case, res)
    assert_same(res, case.c(build))


# ---------------------------------------------------------------- build guards
def _written(tmp_path, precision="float64", cal=None):
    cal = cal or synthetic_calibration("cone6", seed=1)
    mod = generate_c(cal, precision=precision, harness=True)
    write_c(mod, tmp_path)
    return mod


def _cc(args, cwd):
    return subprocess.run(["cc", *args], capture_output=True, text=True, cwd=cwd,
                          check=False)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_every_file_builds_warning_free_under_the_strict_flags(tmp_path, precision):
    """-std=c99 -O2 with -Wall -Wextra -Werror -pedantic, -Wdouble-promotion and
    -Wconversion: the module, the block entry and the harness."""
    _written(tmp_path, precision)
    for f in ("rimu_monitor.c", "rimu_block.c", "rimu_harness.c"):
        r = _cc([*STRICT_FLAGS, "-Wdouble-promotion", "-Wconversion", "-c", f, "-o",
                 f + ".o"], tmp_path)
        assert r.returncode == 0 and not r.stderr.strip(), (f, r.stderr)


def test_fast_math_and_contraction_stop_the_build(tmp_path):
    """-ffast-math: an #error naming the flag; GNU mode on an FMA target (contraction on):
    an #error naming -std=c99; -std=c99 on the same target builds."""
    _written(tmp_path)
    r = _cc(["-std=c99", "-O2", "-ffast-math", "-c", "rimu_monitor.c", "-o", "x.o"],
            tmp_path)
    assert r.returncode != 0 and "#error" in r.stderr and "-ffast-math" in r.stderr
    r = _cc(["-std=c99", "-O2", "-ffinite-math-only", "-c", "rimu_monitor.c", "-o", "x.o"],
            tmp_path)
    assert r.returncode != 0 and "-ffinite-math-only" in r.stderr
    probe = _cc(["-march=haswell", "-dM", "-E", "-x", "c", "/dev/null"], tmp_path)
    if probe.returncode != 0 or "__FP_FAST_FMA " not in probe.stdout:
        pytest.skip("the compiler does not target x86-64 haswell (FMA)")
    r = _cc(["-std=gnu99", "-O2", "-march=haswell", "-c", "rimu_monitor.c", "-o", "x.o"],
            tmp_path)
    assert r.returncode != 0 and "-std=c99" in r.stderr and "contract" in r.stderr
    r = _cc([*STRICT_FLAGS, "-march=haswell", "-c", "rimu_monitor.c", "-o", "x.o"], tmp_path)
    assert r.returncode == 0 and not r.stderr.strip(), r.stderr


# ---------------------------------------------------------------- identity, CRC, state
def test_identity_covers_calibration_thresholds_settings_precision():
    cal = synthetic_calibration("tetrad", seed=1)
    th = default_thresholds(cal)
    base = generate_c(cal)
    assert base.identity == generate_c(cal).identity             # deterministic
    assert f'#define RIMU_IDENTITY "{base.identity}"' in base.files["rimu_monitor.h"]
    others = [generate_c(synthetic_calibration("tetrad", seed=2)),
              generate_c(cal, dataclasses.replace(th, false_alarms_per_hour=
                                                  th.false_alarms_per_hour * 2)),
              generate_c(cal, settings=MonitorSettings(persistence=7)),
              generate_c(cal, precision="float32"),
              generate_c(cal, effects=False),
              generate_c(cal, depth=1)]
    ids = {m.identity for m in others}
    assert base.identity not in ids and len(ids) == len(others)
    assert others[1].fingerprint == base.fingerprint           # what the fingerprint misses


def _lib(tmp_path, mod):
    write_c(mod, tmp_path)
    lib = ctypes.CDLL(str(compile_module(tmp_path).resolve()))
    lib.rimu_monitor_table_crc.restype = ctypes.c_ulong
    lib.rimu_monitor_identity.restype = ctypes.c_char_p
    return lib


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_table_crc_matches_and_catches_a_changed_entry(tmp_path, precision):
    """rimu_monitor_table_crc() over the compiled tables equals RIMU_TABLE_CRC (computed by
    the generator from the same numbers); one pool entry changed in the source: it
    differs from the constant."""
    cal = synthetic_calibration("tetrad", seed=1)
    mod = generate_c(cal, precision=precision, harness=True)
    lib = _lib(tmp_path / "a", mod)
    assert lib.rimu_monitor_table_crc() == mod.table_crc
    assert f"#define RIMU_TABLE_CRC {mod.table_crc:#010x}UL" in mod.files["rimu_monitor.h"]
    assert lib.rimu_monitor_identity().decode() == mod.identity
    text = mod.files["rimu_monitor.c"]
    at = text.index("/* set 0xf: V */") + len("/* set 0xf: V */ ")
    end = text.index(",", at)
    old = text[at:end]
    new = repr(float(old.rstrip("f")) * (1 + 1e-6)) + ("f" if old.endswith("f") else "")
    bad = dataclasses.replace(mod, files=dict(mod.files,
                                              **{"rimu_monitor.c": text[:at] + new + text[end:]}))
    assert _lib(tmp_path / "b", bad).rimu_monitor_table_crc() != mod.table_crc


def test_a_state_init_did_not_set_up_is_refused(tmp_path):
    """A zeroed state: rimu_monitor_step returns RIMU_E_STATE and answers capability none,
    no healthy sensor, NaN rates and an infinite protection level; after init: RIMU_OK.
    rimu_monitor_period_ok: 1 within 0.5-1.5 periods of RIMU_SAMPLE_RATE_HZ, else 0."""
    _written(tmp_path)
    (tmp_path / "main.c").write_text(r'''
#include <math.h>
#include <stdio.h>
#include "rimu_monitor.h"
static rimu_state st;
int main(void)
{
    rimu_answer a;
    rimu_real raw[RIMU_N] = {0};
    int r0 = rimu_monitor_step(&st, 0.0, raw, 0, &a), i, h = 0;
    for (i = 0; i < RIMU_N; i++)
        h += a.healthy[i];
    printf("%d %d %d %d %d\n", r0, a.capability, h, isnan(a.omega[0]) != 0,
           isinf(a.protection_level) != 0);
    rimu_monitor_init(&st);
    r0 = rimu_monitor_step(&st, 0.01, raw, 0, &a);
    printf("%d %d\n", r0, a.capability);
    printf("%d%d%d%d%d\n", rimu_monitor_period_ok(1.0 / RIMU_SAMPLE_RATE_HZ),
           rimu_monitor_period_ok(0.4 / RIMU_SAMPLE_RATE_HZ),
           rimu_monitor_period_ok(1.6 / RIMU_SAMPLE_RATE_HZ), rimu_monitor_period_ok(NAN),
           rimu_monitor_period_ok(INFINITY));
    return 0;
}
''')
    r = _cc([*STRICT_FLAGS, "main.c", "rimu_monitor.c", "-lm", "-o", "main"], tmp_path)
    assert r.returncode == 0, r.stderr
    out = subprocess.run([str(tmp_path / "main")], capture_output=True, text=True,
                         check=True).stdout.split("\n")
    assert out[0] == "1 3 0 1 1"                      # RIMU_E_STATE, RIMU_CAP_NONE
    assert out[1] == "0 0"                            # RIMU_OK, isolate
    assert out[2] == "10000"                          # the rate contract: one period only


# ---------------------------------------------------------------- the 4×MPU9250 set
def _mpu() -> Path | None:
    root = Path(os.environ.get("RIMU_SHARED_DATA",
                               Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
    p = root / "multi_imu_4x_mpu9250"
    return p if all((p / f"imu{k}_raw.mat").is_file() for k in range(1, 5)) else None


def _text_bytes(obj: Path) -> int:
    out = subprocess.run(["size", str(obj)], capture_output=True, text=True, check=True)
    return int(out.stdout.splitlines()[1].split()[0])


@pytest.mark.slow
@pytest.mark.skipif(_mpu() is None, reason="4xMPU9250 recording not in ../shared/data")
def test_mpu9250_set_exports_fits_and_answers_as_the_monitor(tmp_path, capsys):
    """ingest → calibrate static → export: the float32 module's code and tables within
    256 KiB (`size` text, host object: the Cortex-M4 object is smaller) and cone6's within
    64 KiB; on the recording as it is (imu1.y is isolated by the parity) and with a step
    on imu2.y, then imu1 silent (two more exclusions: a sensor, an IMU), it gives the
    monitor's events, healthy sets and capabilities, its numbers within the float32 bound
    (float64 bit-equality on 12 sensors: the four-triad test)."""
    from fdi.calfile import load_calibration
    from replay.flight_io import load_flight_dir
    from rimu.cli import main

    p = _mpu()
    d = tmp_path / "m4"
    assert main(["ingest", *(str(p / f"imu{k}_raw.mat") for k in range(1, 5)),
                 "--out", str(d)]) == 0
    assert main(["calibrate", "static", str(d), "--out", str(tmp_path / "c.json")]) == 0
    capsys.readouterr()
    cal = load_calibration(tmp_path / "c.json")
    flight = load_flight_dir(d)
    names = [s.name for s in cal.gyro.sensors]
    assert cal.gyro.n == 12
    th = default_thresholds(cal)
    # "auto" carries two exclusions within the flash budget
    mod = generate_c(cal, th, precision="float32", harness=True)
    assert mod.depth == 2 and mod.sets == 130
    out = tmp_path / "float32"
    write_c(mod, out)
    mon = CMonitor.load(out, compile_module(out), names)
    r = _cc(["-std=c99", "-O2", "-c", "rimu_monitor.c", "-o", "m.o"], out)
    assert r.returncode == 0 and _text_bytes(out / "m.o") <= 256 << 10
    cone = tmp_path / "cone6"
    _written(cone, "float32")
    assert _cc(["-std=c99", "-O2", "-c", "rimu_monitor.c", "-o", "m.o"], cone).returncode == 0
    assert _text_bytes(cone / "m.o") <= 64 << 10
    raw = flight.raw.copy()
    N = len(raw)
    faulty = raw.copy()
    faulty[N // 3:, 4] += 30 * cal.gyro.noise_sd[4] / cal.gyro.scale_factors[4]
    valid = np.ones(raw.shape, bool) if flight.valid is None else flight.valid.copy()
    fvalid = valid.copy()
    fvalid[2 * N // 3:, 0:3] = False                  # imu1 (its y already out) dies
    for r_, v_, expect in ((raw, valid, ()), (faulty, fvalid, ("isolated", "stale"))):
        res = Monitor(cal, th).run(flight.t, r_, v_, parity=True)
        seen = {e.type for e in res.events} | {e.reason for e in res.events}
        assert set(expect) <= seen, seen
        mon.reset()
        assert_float32_within_the_bound(res, mon.run(flight.t, r_, v_))


# ---------------------------------------------------------------- float32 on a real flight
@pytest.mark.slow
def test_float32_on_erle_flight_41_within_the_restated_bound():
    """The whole of flight 41 through ``rimu monitor-file``'s chain (studies.export_float32):
    the float32 module gives the monitor's events; thresholds within 1e-3 relative (the
    timing-jitter term is on: measured 1.8e-4), protection levels within 1e-4, ω̂ within
    1e-6 of the largest rate, statistics within 1 % (docs/export-c.md, "float32")."""
    from studies.export_float32 import FLIGHTS, measure

    root = Path(os.environ.get("RIMU_SHARED_DATA",
                               Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
    path = root / "erle_pxf_dual_imu" / FLIGHTS["41"]
    if not path.exists():
        pytest.skip(f"{path} not found (set RIMU_SHARED_DATA)")
    m = measure(path)
    assert m["same_events"]
    assert m["max_rel_thresholds"] < 1e-3
    assert m["max_rel_protection_level"] < 1e-4
    assert m["max_rel_omega"] < 1e-6
    assert m["max_rel_statistics"] < 1e-2
