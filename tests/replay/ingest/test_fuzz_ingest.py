"""Damaged logs for every reader: samples, or a RimuError naming the file — nothing else.

The pristine files are written here (DataFlash by struct, ULog through pyulog, CSV,
.mat through scipy.io); hypothesis (bounded) truncates them, flips bytes and inserts
garbage. Every outcome must be a LogRead (pymavlink and pyulog resynchronise over some
damage) or a :class:`~fdi.errors.RimuError` whose message names the file; with
``salvage`` a damaged file that still has IMU samples before the damage must read.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ingest_helpers import small_imu_data, write_dataflash, write_ulog

from fdi.errors import RimuError
from replay.ingest import read_any


def _pristine(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("pristine")
    t, g, a = small_imu_data(n=60)
    write_dataflash(d / "a.BIN", t, g, a)
    n = 40
    rng = np.random.default_rng(0)
    tu = [np.arange(n, dtype=np.uint64) * 4000 + 1_000_000 + 500 * k for k in range(2)]
    gy = [rng.normal(0, 0.1, (n, 3)).astype(np.float32) for _ in range(2)]
    ac = [rng.normal(0, 0.1, (n, 3)).astype(np.float32) for _ in range(2)]
    write_ulog(d / "a.ulg", tu, gy, ac, [np.full(n, 30.0, np.float32)] * 2, [1, 2])
    rows = ["time_ms,imu1_gyr_x_rps,imu1_gyr_y_rps,imu1_gyr_z_rps"]
    rows += [f"{10 * i},{x:.6f},{y:.6f},{z:.6f}" for i, (x, y, z) in enumerate(g[0])]
    (d / "a.csv").write_text("\n".join(rows) + "\n")
    scipy.io.savemat(d / "a.mat", {"imu1_raw": {"t": (t / 1000.0)[:, None], "wb": g[0],
                                                "fb": a[0]}})
    return {p.suffix: p.read_bytes() for p in d.iterdir()}


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    return _pristine(tmp_path_factory)


_damage = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0.0, 1.0)),
    st.tuples(st.just("flip"), st.floats(0.0, 1.0), st.integers(1, 40)),
    st.tuples(st.just("insert"), st.floats(0.0, 1.0), st.binary(min_size=1, max_size=60)),
)


def _apply(data: bytes, dmg) -> bytes:
    at = int(dmg[1] * len(data))
    if dmg[0] == "truncate":
        return data[:at]
    if dmg[0] == "flip":
        b = bytearray(data)
        for k in range(at, min(len(b), at + dmg[2])):
            b[k] ^= 0xA5
        return bytes(b)
    return data[:at] + dmg[2] + data[at:]


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(suffix=st.sampled_from([".BIN", ".ulg", ".csv", ".mat"]), dmg=_damage,
       salvage=st.booleans())
def test_damaged_log_reads_or_fails_with_one_line(pristine, tmp_path, suffix, dmg, salvage):
    p = tmp_path / f"damaged{suffix}"
    p.write_bytes(_apply(pristine[suffix], dmg))
    try:
        r = read_any(p, salvage=salvage)
    except RimuError as exc:
        msg = str(exc)
        assert str(p) in msg and "\n" not in msg
        return
    assert all(np.isfinite(s.t).all() or s.size == 0 for s in r.streams)
    if r.damage is not None:
        assert salvage


def test_ulog_header_damage_does_not_hang(pristine, tmp_path):
    # found by fuzzing: bytes flipped in the definitions make pyulog seek before the
    # start of the file; on a BytesIO that is a ValueError pyulog retries forever
    p = tmp_path / "head.ulg"
    p.write_bytes(_apply(pristine[".ulg"], ("flip", 0.0022461445398733737, 19)))
    with pytest.raises(RimuError, match=r"head\.ulg"):
        read_any(p)
