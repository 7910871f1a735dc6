"""Damaged CAN logs (.log candump, .asc, .blf) through :func:`replay.logio.read_log`.

Pristine logs come from ``rimu simulate flight --out x.{log,asc,blf}`` (python-can's
writers). Hypothesis applies random byte flips, truncation at random offsets, inserted garbage
lines or bytes, duplicated, deleted and shuffled lines. For every damaged file:

* non-strict: no exception, every frame accounted (read = used + rejected), and what lies
  before a truncation is kept;
* strict: success or :class:`fdi.errors.ReplayError`, nothing else.

The real comma2k19 log is read in place (truncated prefixes live in an anonymous in-memory
file, never a copy on disk).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fdi.errors import FileFormatError, ReplayError
from replay.assemble import decode_frames
from replay.can_read import read_frames
from replay.channel_map import load_channel_map
from replay.frames import load_dbc
from replay.logio import read_log
from rimu.cli import main
from studies.synthetic import synthetic_calibration

FUZZ = settings(max_examples=int(os.environ.get("RIMU_FUZZ_EXAMPLES", "30")), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])
CAL = synthetic_calibration("cone6", seed=3, raw_unit="LSB")
SUFFIXES = [".log", ".asc", ".blf"]


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("logs")
    CAL.save(d / "cal.json")
    out = {}
    for sfx in SUFFIXES:
        p = d / f"flight{sfx}"
        with contextlib.redirect_stdout(io.StringIO()):
            code = main(["simulate", "flight", "--cal", str(d / "cal.json"), "--duration",
                         "1", "--seed", "4", "--fault", "step:2:15sigma:0.5", "--out", str(p)])
        assert code == 0
        out[sfx] = p.read_bytes()
    return out


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("damaged")


def _balanced(fr: dict) -> None:
    assert fr["read"] == fr["used"] + sum(fr["rejected"].values()), fr
    assert fr["balanced"], fr


def _check(path: Path) -> dict:
    """Non-strict read never raises and balances; strict read succeeds or ReplayError."""
    _, fr = read_log(path, CAL, progress=False)
    _balanced(fr)
    try:
        _, frs = read_log(path, CAL, strict=True, progress=False)
    except ReplayError as exc:
        assert path.name in str(exc), str(exc)
    else:
        _balanced(frs)
        assert frs["read"] == fr["read"] and frs["used"] == fr["used"]
    return fr


GARBAGE_LINES = [b"garbage", b"(((", b"(1.0) can0", b"(1.0) can0 123#", b"(1.0) can0 123#XYZ",
                 b"(x) can0 101#00", b"(1.0) can0 1FFFFFFFF#00", b"(nan) can0 101#0011",
                 b"(inf) can0 101#00", b"(1.0) can0 101#" + b"00" * 70, b"\x00\xff\xfe",
                 b" 1.000 1 101 Rx d 8 00 00", b" 1.000 1 101 Rx d 9 00 00 00 00 00 00 00 00 00",
                 b" nan 1 101 Rx d 1 00", b"Begin Triggerblock", b"End TriggerBlock",
                 b"base hex timestamps absolute", b"1.0 CANFD 1 Rx 101 0 0 8 8 00 00",
                 b" 1.000 1 101x Rx d 8 00 00 00 00 00 00 00 00", b"\t", b"//"]


@st.composite
def damage(draw, data: bytes, text: bool) -> tuple[bytes, str, int]:
    """(damaged bytes, kind of damage, truncation offset or -1)."""
    kinds = ["flip", "truncate", "insert_bytes", "dup_chunk"]
    if text:
        kinds += ["garbage_line", "dup_line", "del_line", "shuffle", "swap"]
    kind = draw(st.sampled_from(kinds))
    n = len(data)
    if kind == "truncate":
        k = draw(st.integers(0, n - 1))
        return data[:k], kind, k
    if kind == "flip":
        out = bytearray(data)
        for _ in range(draw(st.integers(1, 8))):
            out[draw(st.integers(0, n - 1))] ^= draw(st.integers(1, 255))
        return bytes(out), kind, -1
    if kind == "insert_bytes":
        k = draw(st.integers(0, n))
        return data[:k] + draw(st.binary(min_size=1, max_size=64)) + data[k:], kind, -1
    if kind == "dup_chunk":
        a = draw(st.integers(0, n - 1))
        b = draw(st.integers(a, min(n, a + 4096)))
        k = draw(st.integers(0, n))
        return data[:k] + data[a:b] + data[k:], kind, -1
    lines = data.split(b"\n")
    m = len(lines)
    if kind == "garbage_line":
        for _ in range(draw(st.integers(1, 5))):
            lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from(GARBAGE_LINES)))
    elif kind == "dup_line":
        for _ in range(draw(st.integers(1, 5))):
            i = draw(st.integers(0, len(lines) - 1))
            lines.insert(i, lines[i])
    elif kind == "del_line":
        for _ in range(draw(st.integers(1, 5))):
            if len(lines) > 1:
                del lines[draw(st.integers(0, len(lines) - 1))]
    elif kind == "shuffle":
        a = draw(st.integers(0, m - 1))
        b = draw(st.integers(a, min(m, a + 50)))
        seg = lines[a:b]
        np.random.default_rng(draw(st.integers(0, 2**32 - 1))).shuffle(seg)
        lines[a:b] = seg
    else:
        i, j = draw(st.integers(0, m - 1)), draw(st.integers(0, m - 1))
        lines[i], lines[j] = lines[j], lines[i]
    return b"\n".join(lines), kind, -1


_LOG_FRAME = re.compile(rb"^\(\d+\.\d+\) can\d+ [0-9A-F]+#[0-9A-F]*( R)?$")
_ASC_FRAME = re.compile(rb"^\s*\d+\.\d+\s+\d+\s+[0-9A-Fa-f]+x?\s+Rx\s+d\s+\d+(\s+[0-9A-Fa-f]{2})*")


def _complete_frames_before(data: bytes, k: int, sfx: str) -> int:
    """Frame lines that lie wholly before offset k (an independent count)."""
    head = data[:k]
    whole = head[:head.rfind(b"\n") + 1] if b"\n" in head else b""
    pat = _LOG_FRAME if sfx == ".log" else _ASC_FRAME
    return sum(1 for ln in whole.split(b"\n") if pat.match(ln))


@pytest.mark.parametrize("sfx", SUFFIXES)
@FUZZ
@given(data=st.data())
def test_damaged_log_never_raises_and_accounts_every_frame(logs, work, sfx, data):
    pristine = logs[sfx]
    bad, kind, k = data.draw(damage(pristine, sfx != ".blf"), label="damage")
    p = work / f"damaged{sfx}"
    p.write_bytes(bad)
    if sfx == ".blf" and not bad.startswith(b"LOGG") and b"LOBJ" not in bad:
        # nothing of a BLF file is left: said so, not read as an empty log
        with pytest.raises(FileFormatError, match="not a BLF file"):
            read_log(p, CAL, progress=False)
        return
    fr = _check(p)
    if kind == "truncate" and sfx != ".blf":
        # everything before the cut is kept (the pristine log has no corrupt frame)
        assert fr["used"] >= _complete_frames_before(pristine, k, sfx), (k, fr)
    if kind == "truncate" and sfx == ".blf" and 0 < k < len(pristine):
        # a BLF cut short says so (python-can alone stops silently)
        assert any(e["kind"] in ("truncated", "reader_error", "resync")
                   for e in fr["errors"]), fr


def test_pristine_logs_are_clean(logs, work):
    """The fuzzing starts from logs that read without loss."""
    for sfx, raw in logs.items():
        p = work / f"pristine{sfx}"
        p.write_bytes(raw)
        _, fr = read_log(p, CAL, progress=False)
        assert fr["rejected"] == {} and fr["errors"] == [] and fr["used"] == fr["read"] > 0
        if sfx == ".log":
            assert fr["read"] == _complete_frames_before(raw, len(raw), sfx)
        if sfx == ".asc":
            assert fr["read"] == _complete_frames_before(raw, len(raw), sfx)


# ---------------------------------------------------------------- the real comma2k19 log
DATA = Path(os.environ.get("RIMU_SHARED_DATA", Path(__file__).parents[2] / ".." / "shared"
                          / "data")) / "comma2k19_can"
COMMA = DATA / "rav4_2018-08-02--08-34-47_seg40.candump.log"
COMMA_DBC = DATA / "toyota_2017_kinematics_excerpt.dbc"


@contextlib.contextmanager
def _prefix_in_memory(src: Path, k: int, where: Path):
    """A path ``where/prefix.log`` that reads the first k bytes of ``src`` from an anonymous
    in-memory file (``memfd``): the data set is read in place and never copied to disk."""
    fd = os.memfd_create("rimu-prefix")
    try:
        with src.open("rb") as f:
            os.write(fd, f.read(k))
        link = where / "prefix.log"
        if link.is_symlink():
            link.unlink()
        link.symlink_to(f"/proc/{os.getpid()}/fd/{fd}")
        yield link
    finally:
        os.close(fd)


@pytest.mark.skipif(not COMMA.is_file(), reason="comma2k19 data not present")
def test_comma2k19_truncated_at_random_offsets(tmp_path):
    size = COMMA.stat().st_size
    cmap_path = tmp_path / "comma.toml"
    cmap_path.write_text(f"""schema = "rimu.channel_map/1"
kind = "gyro"
dbc = "{COMMA_DBC.resolve().as_posix()}"
time_tolerance_s = 0.002
[[sensors]]
name = "yaw_rate"
message = "KINEMATICS"
signal = "YAW_RATE"
unit = "deg/s"
channel = 0
""")
    cmap = load_channel_map(cmap_path)
    db = load_dbc(cmap.dbc)
    rng = np.random.default_rng(2019)
    offsets = sorted(int(x) for x in rng.integers(1, size, 3))
    with COMMA.open("rb") as f:
        whole = f.read()
    for k in offsets:
        with _prefix_in_memory(COMMA, k, tmp_path) as p:
            raw, acct = read_frames(p, progress=False)
            try:
                read_frames(p, strict=True, progress=False)
            except ReplayError as exc:
                assert p.name in str(exc)
        decode_frames(raw, db, cmap, acct, sample_rate_hz=83.0)
        d = acct.to_dict()
        assert d["read"] == d["used"] + sum(d["rejected"].values()) and d["balanced"], d
        complete = whole[:k].count(b"\n")
        # every complete line is read as a frame; the cut line is a frame or garbage
        assert complete <= d["read"] <= complete + 1, (k, d["read"], complete)
        assert d["rejected"].get("garbage_line", 0) <= 1, d


def test_blf_with_damaged_header_is_reported_not_refused(logs, work):
    """Regression (hypothesis): a flipped bit in the BLF header's size field made python-can's
    BLFReader raise ValueError in its constructor, which read_frames reported as "no CAN log
    reader for this file" (FileFormatError) even in non-strict mode."""
    raw = bytearray(logs[".blf"])
    raw[4] ^= 0x80                                  # header size 0x90 -> 0x10
    p = work / "header.blf"
    p.write_bytes(bytes(raw))
    frames, acct = read_frames(p, progress=False)
    # since the resynchronising reader (issue 10): the frames are read, the damage reported
    assert len(frames.t) == 600 and acct.errors and acct.errors[0]["kind"] == "resync"
    with pytest.raises(ReplayError, match=r"header\.blf"):
        read_frames(p, strict=True, progress=False)
    _check(p)


def test_scenario_with_huge_noise_factor_injects_instead_of_raising(tmp_path):
    """Regression: ``size = "1e308x"`` on a noise fault raised OverflowError (``size ** 2``)
    out of ``rimu replay --inject``; now the sensor gets non-finite samples, which the
    monitor marks."""
    from replay.flight import simulate_flight
    from replay.scenario import inject, load_scenario

    p = tmp_path / "s.toml"
    p.write_text('schema = "rimu.scenario/1"\n[[faults]]\nkind = "noise"\nsensor = 2\n'
                 'size = "1e308x"\nonset = 0.1\nduration = 0.2\n')
    faults, seed = load_scenario(p, CAL)
    f = simulate_flight(CAL, 0.5, seed=1)
    f2 = inject(f, faults, CAL, seed=seed, source=str(p))
    hit = (f.t >= 0.1 - 1e-12) & (f.t < 0.3 - 1e-12)
    assert not np.isfinite(f2.raw[hit, 1]).any()
    np.testing.assert_array_equal(f2.raw[~hit], f.raw[~hit])
