"""The real comma2k19 RAV4 CAN log: every frame accounted for, YAW_RATE decoded as cantools does."""

import os
import re
from pathlib import Path

import cantools
import numpy as np
import pytest

from replay.accounting import FrameAccounting
from replay.assemble import decode_frames
from replay.can_read import read_frames
from replay.channel_map import load_channel_map
from replay.frames import load_dbc

DATA = Path(os.environ.get("RIMU_SHARED_DATA", Path(__file__).parents[2] / ".." / "shared"
                          / "data")) / "comma2k19_can"
LOG = DATA / "rav4_2018-08-02--08-34-47_seg40.candump.log"
DBC = DATA / "toyota_2017_kinematics_excerpt.dbc"

pytestmark = pytest.mark.skipif(not LOG.is_file(), reason="comma2k19 data not present")


def _map(tmp_path, tol):
    p = tmp_path / "comma.toml"
    p.write_text(f"""schema = "rimu.channel_map/1"
kind = "gyro"
dbc = "{DBC.resolve().as_posix()}"
time_tolerance_s = {tol}
[[sensors]]
name = "yaw_rate"
message = "KINEMATICS"
signal = "YAW_RATE"
unit = "deg/s"
channel = 0
""")
    return load_channel_map(p)


@pytest.fixture(scope="module")
def frames():
    return read_frames(LOG, progress=False)


def test_every_frame_of_the_real_log_accounted(tmp_path, frames):
    raw, acct = frames
    cmap = _map(tmp_path, 0.002)
    s = decode_frames(raw, load_dbc(cmap.dbc), cmap, acct, sample_rate_hz=83.0)
    # independent count straight from the text lines
    lines = [x for x in LOG.read_text().splitlines() if x.strip()]
    assert len(lines) == 135_468
    kin_can0 = sum(1 for x in lines if re.match(r"^\(\S+\) can0 024#", x))
    kin_other = sum(1 for x in lines if re.match(r"^\(\S+\) can(?!0 )\d+ 024#", x))
    d = acct.to_dict()
    assert d["read"] == 135_468 and d["balanced"], d
    assert d["rejected"].get("unknown_id", 0) == 135_468 - kin_can0 - kin_other
    assert d["rejected"].get("other_channel", 0) == kin_other
    assert d["used"] + d["rejected"].get("duplicate", 0) == kin_can0
    assert d["used"] == s.t.size and s.valid.all()
    # README: YAW_RATE spans -2.27 ... +0.42 deg/s in this segment
    assert s.raw.min() == pytest.approx(-2.268, abs=1e-9)
    assert s.raw.max() == pytest.approx(0.416, abs=1e-9)


def test_vectorised_yaw_rate_equals_cantools_on_every_frame(tmp_path, frames):
    raw, _ = frames
    cmap = _map(tmp_path, 1e-9)
    acct = FrameAccounting()
    s = decode_frames(raw, load_dbc(cmap.dbc), cmap, acct, sample_rate_hz=83.0)
    db = cantools.database.load_file(str(DBC))
    msg = db.get_message_by_frame_id(36)
    ref = [(raw.t[i], msg.decode(raw.data(i), decode_choices=False)["YAW_RATE"])
           for i in range(len(raw)) if raw.arbitration_id[i] == 36 and raw.channel[i] == 0]
    assert acct.rejected.get("duplicate", 0) == 0
    assert len(ref) == s.t.size
    np.testing.assert_array_equal(s.t, [r[0] for r in ref])
    np.testing.assert_array_equal(s.raw[:, 0], [r[1] for r in ref])
