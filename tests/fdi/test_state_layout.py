"""The kernel's array layout comes from one table (fdi.state.LAYOUT, SET_PARTS,
STATE_PARTS): the parts tile the flat arrays, the views are views of them, the generated C
enumerations carry the same numbers."""

from __future__ import annotations

import re

import numpy as np
import pytest

from fdi import state as S
from fdi.export import generate_c
from fdi.monitor import Monitor
from studies.synthetic import synthetic_calibration


@pytest.mark.parametrize("n, nw, ring", [(4, 3, 9), (6, 8, 129), (9, 1, 2)])
def test_parts_tile_the_flat_arrays(n, nw, ring):
    """Consecutive parts, no gap, no overlap; the last one ends the array."""
    for parts, size in ((S.SET_PARTS, None), (S.STATE_PARTS, S.state_size(n, ring))):
        at = 0
        for name, part in parts.items():
            assert S.offset(part, n, nw if parts is S.SET_PARTS else 0) == at, name
            at += len(S.span(np.zeros(10_000), part, n, nw if parts is S.SET_PARTS else 0))
        if size is not None:
            assert size == at + (ring + 1) * (n + 1)
    df = n - 3
    assert S.set_layout(n, df, nw)[2] == S.offset(S.SET_MATS, n, nw) + (3 * df + 3) * n


def test_views_share_the_packed_arrays():
    """KernelSet's and DetectorState's named arrays are views of the one array the kernel
    takes, and together with the scratch they cover it."""
    mon = Monitor(synthetic_calibration("cone6", seed=1))
    ks, st = mon._kset, mon._state
    views = (ks.fconst, ks.sensors, ks.scales, ks.mats)
    assert all(np.shares_memory(v, ks.packed) for v in views)
    assert sum(v.size for v in views) + S.I_SLOTS == ks.packed.size
    np.testing.assert_array_equal(ks.packed[S.SET_ICONST0:S.SET_SENSORS0], ks.iconst)
    assert ks.fconst[S.READMIT_GATE] == mon.settings.readmit_gate
    for v in (st.sensor, st.cusum, st.omega_prev, st.windows):
        assert np.shares_memory(v, st.values)
    assert st.counters.size == S.HEALTH0 + mon.n


def test_c_enumerations_are_the_tables():
    """Every slot name of the generated C has its number in fdi.state."""
    text = generate_c(synthetic_calibration("tetrad", seed=1)).files["rimu_monitor.c"]
    found = dict((k, int(v)) for k, v in re.findall(r"\b([A-Z][A-Z0-9_]*) = (\d+)", text))
    for names in S.LAYOUT:
        for k, v in names.values.items():
            assert found.get(k) == v == getattr(S, k), k
