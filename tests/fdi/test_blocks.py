"""The answer stacked in one place (fdi.blocks) and the one capability table (issue 17 item 5).

- a block built from stepped answers equals ``Monitor.run``'s block on the same samples,
  field by field, with the same dtypes (capability as objects) and, for an empty block, the
  same widths (parity max(n − 3, 0), not 1);
- a field added to both Answer and BlockResult flows through without an edit;
- the capability codes of the kernel and of fdi.state are the positions in
  fdi.answer.CAPABILITIES.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import fdi.blocks as blocks
from fdi import kernel, state
from fdi.answer import CAPABILITIES, Answer, BlockResult
from fdi.blocks import CAPABILITY_CODE, block_from_answers, capability_names
from fdi.monitor import Monitor
from replay.flight import simulate_flight
from replay.live import Pacer
from studies.synthetic import synthetic_calibration


@pytest.fixture(scope="module")
def cal():
    return synthetic_calibration("tetrad", seed=3)


def _fields(b: BlockResult) -> dict[str, np.ndarray]:
    return {f.name: getattr(b, f.name) for f in dataclasses.fields(BlockResult)
            if f.name != "events"}


def test_stepped_block_equals_the_block_path(cal):
    f = simulate_flight(cal, 2.0, seed=4)
    mon = Monitor(cal)
    ref = mon.run(f.t, f.raw, f.valid, parity=True)
    mon.reset()
    answers = [mon.step(float(f.t[k]), f.raw[k], f.valid[k]) for k in range(f.t.size)]
    got = block_from_answers(answers, mon.n, mon.K)
    for name, v in _fields(ref).items():
        g = getattr(got, name)
        assert g.dtype == v.dtype and g.shape == v.shape, name
        np.testing.assert_array_equal(g, v, err_msg=name)
    assert got.events == ref.events
    assert got.capability.dtype == blocks.CAPABILITY_DTYPE
    assert Pacer().run(Monitor(cal), f.t[:3], f.raw[:3], f.valid[:3]).capability.dtype \
        == ref.capability.dtype


def test_empty_block_has_the_widths_of_the_block_path(cal):
    mon = Monitor(cal)
    ref = mon.run(np.zeros(0), np.zeros((0, mon.n)), parity=True)
    got = block_from_answers([], mon.n, mon.K)
    for name, v in _fields(ref).items():
        g = getattr(got, name)
        assert g.shape == v.shape and g.dtype == v.dtype, (name, g.shape, v.shape)
    assert got.parity.shape == (0, max(mon.n - 3, 0))
    assert block_from_answers([], 3, 2).parity.shape == (0, 0)
    assert block_from_answers([], 4, 2, parity=False).parity is None


def test_a_new_field_flows_through(cal, monkeypatch):
    """A field added to both Answer and BlockResult is stacked without an edit of
    fdi.blocks (a per-sample code and a per-axis flag here)."""
    @dataclasses.dataclass(frozen=True)
    class A2(Answer):
        novel_code: int = 0
        novel_flags: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3, bool))

    @dataclasses.dataclass(frozen=True)
    class B2(BlockResult):
        novel_code: np.ndarray | None = None
        novel_flags: np.ndarray | None = None

    monkeypatch.setattr(blocks, "Answer", A2)
    monkeypatch.setattr(blocks, "BlockResult", B2)
    mon = Monitor(cal)
    f = simulate_flight(cal, 0.2, seed=5)
    answers = []
    for k in range(f.t.size):
        a = mon.step(float(f.t[k]), f.raw[k], f.valid[k])
        answers.append(A2(**{x.name: getattr(a, x.name) for x in dataclasses.fields(Answer)},
                          novel_code=k % 3, novel_flags=np.array([k % 2 == 0, False, True])))
    b = block_from_answers(answers, mon.n, mon.K)
    assert b.novel_code.dtype == np.int64
    assert b.novel_code.tolist() == [k % 3 for k in range(f.t.size)]
    assert b.novel_flags.dtype == bool and b.novel_flags.shape == (f.t.size, 3)
    assert b.novel_flags[:, 0].tolist() == [k % 2 == 0 for k in range(f.t.size)]
    e = block_from_answers([], mon.n, mon.K)
    assert e.novel_code.shape == (0,)      # an unknown field: one value per sample


def test_one_capability_table():
    assert state.CAPABILITY_CODE is CAPABILITY_CODE
    assert list(CAPABILITY_CODE) == list(CAPABILITIES)
    assert kernel._NONE == CAPABILITY_CODE["none"]
    codes = np.array([CAPABILITY_CODE[c] for c in CAPABILITIES])
    assert capability_names(codes).tolist() == list(CAPABILITIES)
