"""Adversarial blocks for :meth:`fdi.monitor.Monitor.run`.

Two properties (hypothesis, seeded through the profile, bounded by ``max_examples``):

* garbage of any kind (wrong shapes, NaN/inf/1e300 columns, object and complex arrays, empty
  and 1-D blocks, valid masks of the wrong shape or type, non-monotonic and NaN times) never
  raises and gives a result of the documented shapes;
* wherever the block is well-formed (an (N, n) array with any values, a valid mask of shape
  (N, n) of bool or 0/1 ints, any float times) the block answers equal stepping row by row
  through :meth:`Monitor.step` bit for bit, events included.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fdi.detector import default_thresholds
from fdi.monitor import Monitor
from studies.synthetic import raw_samples, synthetic_calibration

FS = 100.0
_CAL: dict[str, tuple] = {}


def _setup(cfg: str, detector: str) -> tuple:
    """(cal, thresholds, healthy raw block (400, n)) for a configuration, cached."""
    key = f"{cfg}/{detector}"
    if key not in _CAL:
        cal = synthetic_calibration(cfg, seed=5)
        N = 400
        tt = np.arange(N) / FS
        om = 0.5 * np.column_stack([np.sin(2 * np.pi * 0.3 * tt), np.cos(2 * np.pi * 0.2 * tt),
                                    np.sin(2 * np.pi * 0.1 * tt + 1.0)])
        raw = raw_samples(cal, om, seed=9)
        _CAL[key] = (cal, default_thresholds(cal, detector=detector), raw)
    return _CAL[key]


BAD = [np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, 5e-324, 1e20]


def _events_key(events) -> list[str]:
    """Events as reprs: NaN fields compare equal, floats exactly (repr round-trips)."""
    return [repr(e) for e in events]


def assert_identical(answers, res) -> None:
    """Block result equals the stepped answers bit for bit (NaN equal to NaN)."""
    assert len(res) == len(answers)
    if not answers:
        return
    np.testing.assert_array_equal(np.array([a.t for a in answers]), res.t, err_msg="t")
    for name in ("omega", "omega_sd", "healthy", "statistics", "thresholds", "parity"):
        np.testing.assert_array_equal(np.array([getattr(a, name) for a in answers]),
                                      getattr(res, name), err_msg=name)
    np.testing.assert_array_equal(np.array([a.protection_level for a in answers]),
                                  res.protection_level, err_msg="protection_level")
    assert [a.capability for a in answers] == list(res.capability), "capability"
    assert _events_key(e for a in answers for e in a.events) == _events_key(res.events)


# ---------------------------------------------------------------- well-formed blocks
@st.composite
def wellformed(draw):
    cfg = draw(st.sampled_from(["cone6", "tetrad"]))
    detector = draw(st.sampled_from(["windows", "both"]))
    cal, th, base = _setup(cfg, detector)
    n = cal.gyro.n
    N = draw(st.integers(0, 300))
    r0 = draw(st.integers(0, base.shape[0] - N))
    raw = base[r0:r0 + N].copy()
    t = np.arange(N) / FS
    valid = None
    for _ in range(draw(st.integers(0, 6))):
        if N == 0:
            break
        kind = draw(st.sampled_from(["cell", "column", "stuck", "tnan", "tback", "tjump",
                                     "miss", "tdup"]))
        row = draw(st.integers(0, N - 1))
        col = draw(st.integers(0, n - 1))
        if kind == "cell":
            raw[row, col] = draw(st.sampled_from(BAD))
        elif kind == "column":
            raw[row:, col] = draw(st.sampled_from(BAD))
        elif kind == "stuck":
            raw[row:, col] = raw[row, col]
        elif kind == "tnan":
            t[row] = np.nan
        elif kind == "tback":
            t[row:] -= draw(st.floats(0.0, 10.0))
        elif kind == "tjump":
            t[row:] += draw(st.sampled_from([0.5, 1.0, 100.0, np.inf]))
        elif kind == "tdup":
            t[row:] = t[row]
        else:
            if valid is None:
                valid = np.ones((N, n), bool)
            valid[row:row + draw(st.integers(1, 50)), col] = False
    if valid is not None and draw(st.booleans()):
        valid = valid.astype(draw(st.sampled_from([np.int8, np.int64, np.float64])))
    chunk = draw(st.sampled_from([1, 2, 7, 64, 8192]))
    return cal, th, t, raw, valid, chunk


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.data_too_large])
@given(wellformed())
def test_run_equals_step_on_wellformed_blocks_with_bad_numbers(case):
    cal, th, t, raw, valid, chunk = case
    a = Monitor(cal, th)
    answers = [a.step(t[i], raw[i], None if valid is None else valid[i])
               for i in range(len(t))]
    res = Monitor(cal, th).run(t, raw, valid, parity=True, chunk=chunk)
    assert_identical(answers, res)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.data_too_large])
@given(wellformed(), st.integers(1, 5))
def test_run_in_pieces_equals_one_run(case, pieces):
    """Feeding a block in several run() calls continues the state exactly."""
    cal, th, t, raw, valid, chunk = case
    res = Monitor(cal, th).run(t, raw, valid, parity=True, chunk=chunk)
    mon = Monitor(cal, th)
    cuts = np.linspace(0, len(t), pieces + 1).astype(int)
    parts = [mon.run(t[a:b], raw[a:b], None if valid is None else valid[a:b], parity=True,
                     chunk=chunk) for a, b in pairwise(cuts)]
    for name in ("omega", "healthy", "statistics", "thresholds", "parity", "protection_level"):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in parts]),
                                      getattr(res, name), err_msg=name)
    assert _events_key(e for p in parts for e in p.events) == _events_key(res.events)


# ---------------------------------------------------------------- garbage blocks
def _garbage_raw(draw, n: int, base: np.ndarray):
    N = draw(st.integers(0, 40))
    kind = draw(st.sampled_from(["ok", "wide", "narrow", "1d", "3d", "scalar", "empty",
                                 "object", "strings", "complex", "int", "bool", "ragged",
                                 "none", "nested_none", "generator", "dict", "bytes"]))
    block = base[:N].copy()
    if kind == "ok":
        return N, block
    if kind == "wide":
        return N, np.column_stack([block, np.ones(N)])
    if kind == "narrow":
        return N, block[:, :-1]
    if kind == "1d":
        return N, block[:, 0]
    if kind == "3d":
        return N, block[:, :, None]
    if kind == "scalar":
        return N, draw(st.sampled_from([np.float64(1.0), 3, np.nan, "x"]))
    if kind == "empty":
        return N, np.empty((0, n))
    if kind == "object":
        o = block.astype(object)
        if N:
            o[draw(st.integers(0, N - 1)), draw(st.integers(0, n - 1))] = \
                draw(st.sampled_from([None, "abc", [1, 2], {}, 1j, object()]))
        return N, o
    if kind == "strings":
        return N, block.astype(str)
    if kind == "complex":
        return N, block + 1j
    if kind == "int":
        return N, block.astype(np.int64)
    if kind == "bool":
        return N, block > block.mean()
    if kind == "ragged":
        rows = [list(r) for r in block]
        if rows:
            rows[draw(st.integers(0, N - 1))].append(1.0)
        return N, rows
    if kind == "none":
        return N, None
    if kind == "nested_none":
        return N, [None] * N
    if kind == "generator":
        return N, (r for r in block)
    if kind == "dict":
        return N, {"a": 1}
    return N, b"\x00\x01garbage"


def _garbage_t(draw, N: int):
    kind = draw(st.sampled_from(["ok", "nan", "back", "short", "long", "2d", "object",
                                 "strings", "none", "scalar", "inf"]))
    t = np.arange(N) / FS
    if kind == "ok":
        return t
    if kind == "nan":
        return np.full(N, np.nan)
    if kind == "back":
        return t[::-1].copy()
    if kind == "short":
        return t[:max(N - 3, 0)]
    if kind == "long":
        return np.arange(N + 5) / FS
    if kind == "2d":
        return t[:, None]
    if kind == "object":
        o = t.astype(object)
        if N:
            o[0] = None
        return o
    if kind == "strings":
        return [f"{x}s" for x in t]
    if kind == "none":
        return None
    if kind == "scalar":
        return 1.5
    return np.full(N, np.inf)


def _garbage_valid(draw, N: int, n: int):
    kind = draw(st.sampled_from(["none", "ok", "transposed", "1d", "short", "object",
                                 "int", "strings", "scalar", "ragged", "float_nan"]))
    if kind == "none":
        return None
    if kind == "ok":
        return np.ones((N, n), bool)
    if kind == "transposed":
        return np.ones((n, N), bool)
    if kind == "1d":
        return np.ones(N, bool)
    if kind == "short":
        return np.ones((max(N - 1, 0), n), bool)
    if kind == "object":
        o = np.ones((N, n), object)
        if N:
            o[0, 0] = None
        return o
    if kind == "int":
        return np.full((N, n), 2)
    if kind == "strings":
        return np.full((N, n), "no")
    if kind == "scalar":
        return False
    if kind == "ragged":
        return [[True] * (n + (i % 2)) for i in range(N)]
    return np.full((N, n), np.nan)


@st.composite
def garbage(draw):
    cfg = draw(st.sampled_from(["cone6", "tetrad"]))
    detector = draw(st.sampled_from(["windows", "both"]))
    cal, th, base = _setup(cfg, detector)
    n = cal.gyro.n
    N, raw = _garbage_raw(draw, n, base)
    if isinstance(raw, np.ndarray) and raw.dtype.kind == "f" and raw.ndim == 2 and raw.size:
        for _ in range(draw(st.integers(0, 3))):
            raw[:, draw(st.integers(0, raw.shape[1] - 1))] = draw(st.sampled_from(BAD))
    t = _garbage_t(draw, N)
    valid = _garbage_valid(draw, N, n)
    chunk = draw(st.sampled_from([1, 5, 8192, 0, -3]))
    return cal, th, t, raw, valid, chunk


def _check_shapes(res, n: int, K: int) -> None:
    N = len(res)
    assert res.t.shape == (N,)
    assert res.omega.shape == (N, 3) and res.omega_sd.shape == (N, 3)
    assert res.healthy.shape == (N, n) and res.healthy.dtype == bool
    assert res.statistics.shape == (N, K) and res.thresholds.shape == (N, K)
    assert res.protection_level.shape == (N,)
    assert res.capability.shape == (N,)
    if res.parity is not None:
        assert res.parity.shape == (N, max(n - 3, 0))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                   HealthCheck.data_too_large])
@given(garbage())
def test_run_never_raises_on_garbage(case):
    cal, th, t, raw, valid, chunk = case
    mon = Monitor(cal, th)
    res = mon.run(t, raw, valid, parity=True, chunk=chunk)
    _check_shapes(res, mon.n, mon.K)
    # the monitor keeps working on good data afterwards (no stuck internal state)
    _, _, base = _setup("cone6" if mon.n == 6 else "tetrad", th.detector)
    t0 = 1000.0
    res2 = mon.run(t0 + np.arange(5) / FS, base[:5], parity=True)
    _check_shapes(res2, mon.n, mon.K)
    assert np.all(np.isfinite(res2.omega[res2.capability != "none"])), res2.omega


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.data_too_large])
@given(garbage())
def test_run_equals_step_on_row_iterable_garbage(case):
    """Blocks the block path cannot vectorise still answer as stepping their rows."""
    cal, th, t, raw, valid, chunk = case
    if not isinstance(raw, np.ndarray | list) or (isinstance(raw, np.ndarray) and raw.ndim != 2):
        return
    try:
        ts = np.asarray(t, float).reshape(-1)
    except (TypeError, ValueError):
        return
    if valid is not None and not isinstance(valid, np.ndarray | list):
        return
    rows = list(raw)
    N = min(len(rows), len(ts))
    vl = None if valid is None else list(valid)
    a = Monitor(cal, th)
    answers = [a.step(ts[i], rows[i], None if vl is None or i >= len(vl) else vl[i])
               for i in range(N)]
    res = Monitor(cal, th).run(t, raw, valid, parity=True, chunk=chunk)
    assert_identical(answers, res)


def test_complex_block_is_marked_as_step_marks_it():
    """Regression (hypothesis): run() cast a complex block to its real part (with a
    ComplexWarning) and carried on, while step() marks complex values non-finite."""
    cal, th, base = _setup("cone6", "windows")
    raw = base[:20] + 1j
    t = np.arange(20) / FS
    a = Monitor(cal, th)
    answers = [a.step(t[i], raw[i]) for i in range(20)]
    res = Monitor(cal, th).run(t, raw, parity=True)
    assert_identical(answers, res)
    assert not res.healthy[-1].any()
    assert res.healthy[0].sum() == 0 and answers[0].status[0] == "nonfinite"


@pytest.mark.slow
@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                    HealthCheck.data_too_large])
@given(wellformed())
def test_run_equals_step_heavy(case):
    test_run_equals_step_on_wellformed_blocks_with_bad_numbers.hypothesis.inner_test(case)
