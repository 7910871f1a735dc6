"""The exported C monitor on its target: cross-compiled for a Cortex-M4F
(``arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16 -O2
-std=c99``, warning-free under the strict flags) and run under ``qemu-system-arm -M
mps2-an386`` with semihosting (:mod:`fdi.export.target`).

Its answers are compared bit for bit with the host build of the same module (x86-64,
``cc -std=c99 -O2``: every number of every answer, every event) and with
:class:`fdi.monitor.Monitor` (float64: ``assert_same``; float32: the same events within
the float32 bound), on a simulated cone6 flight with faults and on a cut of erle flight 41
of ``../shared/data`` with a step injected. ``--slow``; skipped, saying what is missing,
without the toolchain (``.ci/run`` installs it).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from test_export_c import assert_float32_within_the_bound, assert_same
from test_monitor import scenario

from fdi.detector import default_thresholds
from fdi.export import generate_c, write_c
from fdi.export.host import CMonitor, compile_module, find_compiler
from fdi.export.target import build_target, find_toolchain, run_target
from fdi.monitor import Monitor

MISSING = find_toolchain() if find_compiler() else "no C compiler (cc) on the PATH"
pytestmark = [pytest.mark.slow, pytest.mark.skipif(MISSING is not None, reason=str(MISSING))]

ARRAYS = ("omega", "omega_sd", "parity", "statistics", "thresholds", "protection_level")


def assert_bit_identical(host, target) -> None:
    """Every number of every answer equal to the bit, the discrete fields and every event
    (its numbers to the bit too)."""
    for name in ARRAYS:
        a = np.ascontiguousarray(getattr(host, name), float)
        b = np.ascontiguousarray(getattr(target, name), float)
        assert a.shape == b.shape, name
        diff = np.flatnonzero(a.view(np.uint64) != b.view(np.uint64))
        assert diff.size == 0, f"{name}: {diff.size} values differ, first at {diff[0]}"
    for name in ("healthy", "status", "capability", "suspects", "unverified", "envelope"):
        assert np.array_equal(np.asarray(getattr(host, name)),
                              np.asarray(getattr(target, name))), name
    assert np.array_equal(host.event_rows, target.event_rows)
    for a, b in zip(host.events, target.events, strict=True):
        assert (a.t, a.sensor, a.type, a.reason, a.scale, a.sensors, a.envelope) == \
               (b.t, b.sensor, b.type, b.reason, b.scale, b.sensors, b.envelope)
        for f in ("statistic", "threshold", "magnitude"):
            x = np.float64(np.nan if getattr(a, f) is None else getattr(a, f))
            y = np.float64(np.nan if getattr(b, f) is None else getattr(b, f))
            assert x.view(np.uint64) == y.view(np.uint64), (a.type, a.t, f)


def _on_target(tmp_path, cal, th, precision, t, raw, valid):
    mod = generate_c(cal, th, precision=precision, harness=True)
    write_c(mod, tmp_path)
    names = [s.name for s in cal.gyro.sensors]
    host = CMonitor.load(tmp_path, compile_module(tmp_path), names)
    h = host.run(t, raw, valid)
    run = run_target(build_target(tmp_path, t, raw, valid), names,
                     float32=precision == "float32", parity_len=host.P, K=host.K)
    assert run.steps == len(t) and run.crc_ok
    # sizeof(rimu_answer) of cone6 float32 / float64 since the answer carries time_status
    assert run.answer_bytes in (776, 992) and run.stack_bytes < 4096
    return h, run


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_simulated_flight_with_faults_on_the_cortex_m4f(tmp_path, precision):
    cal, t, raw, _ = scenario("cone6", 2000, [(3, 500, 8.0), (5, 1100, -10.0)], seed=4)
    valid = np.ones(raw.shape, bool)
    valid[300, 1] = False
    valid[700:703, 3] = False
    raw[1700:, 0] = raw[1700, 0]                          # stuck
    th = default_thresholds(cal)
    res = Monitor(cal, th).run(t, raw, valid, parity=True)
    assert {"isolated", "health"} <= {e.type for e in res.events}
    h, run = _on_target(tmp_path, cal, th, precision, t, raw, valid)
    assert_bit_identical(h, run.result)
    if precision == "float64":
        assert_same(res, run.result)
    else:
        assert_float32_within_the_bound(res, run.result)


def test_erle_flight_on_the_cortex_m4f(tmp_path):
    """3000 samples of flight 41 from mid-flight (in-flight calibration), a 0.2 rad/s step
    on the second gyro from the middle of the cut: the float32 module on the target gives
    the host build's answers to the bit and the monitor's events."""
    data = Path(os.environ.get("RIMU_SHARED_DATA",
                               Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
    path = data / "erle_pxf_dual_imu" / "pxf_copter_22-12-2014_41.BIN"
    if not path.exists():
        pytest.skip(f"{path} not found (set RIMU_SHARED_DATA)")
    from studies.field import inflight_calibration, load_erle

    flight = load_erle(path)
    cal = inflight_calibration(flight)
    th = default_thresholds(cal)
    a = len(flight.t) // 2
    t = flight.t[a:a + 3000]
    raw = flight.raw[a:a + 3000].copy()
    raw[1500:, 1] += 0.2 / cal.gyro.scale_factors[1]
    valid = None if flight.valid is None else flight.valid[a:a + 3000]
    res = Monitor(cal, th).run(t, raw, valid, parity=True)
    assert "detected" in {e.type for e in res.events}
    h, run = _on_target(tmp_path, cal, th, "float32", t, raw, valid)
    assert_bit_identical(h, run.result)
    assert_float32_within_the_bound(res, run.result)
