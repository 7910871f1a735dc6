"""The suffix → reader registry of CAN logs (:data:`replay.can_read.CAN_READERS`)."""

from pathlib import Path

import can
import pytest

import replay.can_read as cr
from replay.can_gather import FrameGather
from replay.can_text import read_asc, read_candump


@pytest.mark.parametrize(("name", "reader"), [
    ("f.log", read_candump), ("F.LOG", read_candump), ("f.asc", read_asc),
    ("f.Asc", read_asc), ("f.blf", cr.read_blf), ("f.csv", cr.read_other),
    ("f.trc", cr.read_other), ("f.log.gz", cr.read_other), ("f.blf.GZ", cr.read_other),
    ("f.xyz", cr.read_other), ("f", cr.read_other)])
def test_reader_by_suffix(name, reader):
    """Text logs and BLF by their resuming readers; compressed logs and the rest by
    python-can's own reader."""
    assert cr.reader_for(Path(name)) is reader


def test_a_registered_suffix_is_read_by_its_reader(tmp_path, monkeypatch):
    """One entry in the registry is all a new format needs: read_frames uses it."""
    def read_two(p: Path, g: FrameGather, acct, strict: bool, bar) -> None:
        for k in range(2):
            g.add(can.Message(timestamp=float(k), arbitration_id=0x101 + k, data=b"\x01\x02",
                              channel="can1"))

    monkeypatch.setitem(cr.CAN_READERS, ".two", read_two)
    p = tmp_path / "x.two"
    p.write_text("")
    frames, acct = cr.read_frames(p, progress=False)
    assert frames.t.tolist() == [0.0, 1.0]
    assert frames.arbitration_id.tolist() == [0x101, 0x102]
    assert frames.channel.tolist() == [1, 1]        # "can1" as the map's channel number
    assert acct.read == 0 and acct.errors == []
