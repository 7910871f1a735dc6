"""A flipped byte inside a DataFlash FMT definition (issue 30): the definition is validated
and repaired from what is intact, or its type is framed and skipped with a named warning;
the rest of the log is never misframed. Measured on a real log by
``python -m studies.dataflash_fmt_flips`` (docs/edges.md)."""

from __future__ import annotations

import numpy as np
import pytest
from ingest_helpers import small_imu_data, write_dataflash

from fdi.errors import FileFormatError
from replay.ingest.ardupilot import fmt_repairs, read_ardupilot

FMT = 89


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    t, g, a = small_imu_data(n=120, k=2, seed=3)
    p = tmp_path_factory.mktemp("df") / "two.BIN"
    write_dataflash(p, t, g, a)
    return p, p.read_bytes(), read_ardupilot(p)


def _flip(tmp_path, data: bytes, pos: int, x: int):
    bad = bytearray(data)
    bad[pos] ^= x
    q = tmp_path / f"f{pos}_{x}.BIN"
    q.write_bytes(bytes(bad))
    return q


# bytes of the IMU definition (the writer puts it first, at byte 0)
CASES = {"sync byte": 1, "type id": 3, "length": 4, "name": 6, "format char": 10, "column name": 27}


@pytest.mark.parametrize("field", list(CASES))
def test_one_damaged_field_is_repaired_with_a_warning(log, tmp_path, field):
    _, data, pristine = log
    q = _flip(tmp_path, data, CASES[field], 0x21)
    with pytest.raises(FileFormatError, match="damaged FMT definition at byte 0"):
        read_ardupilot(q)
    got = read_ardupilot(q, salvage=True)
    assert [s.size for s in got.streams] == [s.size for s in pristine.streams]
    for s, s0 in zip(got.streams, pristine.streams, strict=True):
        np.testing.assert_array_equal(s.gyro, s0.gyro)
    warns = [w for w in got.meta.get("warnings", []) if "damaged FMT" in w]
    assert len(warns) == 1, got.meta


def test_unrepairable_type_is_framed_and_skipped_not_misframed(tmp_path):
    """One IMU (no sibling to copy from), its format and length both damaged beyond
    repair: the IMU is skipped with a warning naming it, the log is not misframed (the
    refusal says no IMU message, it does not invent samples)."""
    t, g, a = small_imu_data(n=50, k=1, seed=1)
    p = tmp_path / "one.BIN"
    write_dataflash(p, t, g, a)
    data = p.read_bytes()
    bad = bytearray(data)
    bad[10] = ord("?")  # an unknown format character: no sibling
    patches, warnings = fmt_repairs(bytes(bad))
    assert list(patches) == [0] and "IMU messages framed (31 bytes) but not read" in warnings[0]
    q = tmp_path / "bad.BIN"
    q.write_bytes(bytes(bad))
    with pytest.raises(FileFormatError, match="no IMU messages"):
        read_ardupilot(q, salvage=True)


def test_pristine_logs_have_nothing_to_repair(log):
    _, data, _ = log
    assert fmt_repairs(data) == ({}, [])


@pytest.mark.parametrize("name", ["pxf_copter_22-12-2014_41.BIN", "pxf_copter_31-3-2015_83.BIN"])
def test_real_logs_have_nothing_to_repair(name):
    from ingest_helpers import data_file

    assert fmt_repairs(data_file("erle_pxf_dual_imu", name).read_bytes()) == ({}, [])
