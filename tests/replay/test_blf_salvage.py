"""One flipped byte in a BLF log (issue 30): what :class:`replay.blf.ResyncBLFReader` keeps.

Small logs written by python-can's BLF writer (default 128 KiB containers), compressed and
uncompressed; one byte XORed at seeded random positions. Every frame carries a unique
counter, so a frame is kept when its (time, id, data) is read back. Measured at scale by
``python -m studies.blf_flips`` (docs/edges.md, "Damaged logs").
"""

from __future__ import annotations

import zlib
from collections import Counter
from pathlib import Path

import can
import numpy as np
import pytest

from replay.blf import ResyncBLFReader, _inflate
from replay.can_read import read_frames

N = 6000
PER_CONTAINER = can.BLFWriter.max_container_size / 48  # 48-byte CAN objects
BUDGET = 0.02 * PER_CONTAINER  # the 2 % of a container


def _write(path: Path, level: int, n: int = N) -> bytes:
    rng = np.random.default_rng(7)
    with can.BLFWriter(str(path), compression_level=level) as w:
        for k in range(n):
            w.on_message_received(
                can.Message(
                    timestamp=1_767_225_600.0 + k * 1e-3,
                    arbitration_id=0x100 + k % 6,
                    is_extended_id=False,
                    data=int(k).to_bytes(4, "little") + rng.bytes(4),
                )
            )
    return path.read_bytes()


def _read(path: Path) -> tuple[Counter, ResyncBLFReader]:
    r = ResyncBLFReader(path)
    got = Counter(
        (round(m.timestamp - r.start_timestamp, 4), m.arbitration_id, bytes(m.data)) for m in r
    )
    return got, r


def _containers(raw: bytes) -> list[tuple[int, int]]:
    out, pos = [], int.from_bytes(raw[4:8], "little")
    while pos + 16 <= len(raw):
        size = int.from_bytes(raw[pos + 8 : pos + 12], "little")
        out.append((pos, size))
        pos += size + size % 4
    return out


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, tuple[Path, bytes, Counter]]:
    d = tmp_path_factory.mktemp("blf")
    out = {}
    for name, level in (("compressed", -1), ("plain", 0)):
        p = d / f"{name}.blf"
        raw = _write(p, level)
        truth, r = _read(p)
        assert sum(truth.values()) == N and not r.damage
        out[name] = (p, raw, truth)
    return out


def _flip(tmp_path: Path, raw: bytes, pos: int, x: int) -> Path:
    bad = bytearray(raw)
    bad[pos] ^= x
    q = tmp_path / f"flip{pos}.blf"
    q.write_bytes(bytes(bad))
    return q


def _positions(raw: bytes, kind: str) -> list[int]:
    heads = list(range(144))
    body = []
    for pos, size in _containers(raw):
        heads += range(pos, pos + 32)
        body += range(pos + 32, pos + size)
    return heads if kind == "header" else body


@pytest.mark.parametrize(
    ("name", "kind"), [("plain", "header"), ("plain", "body"), ("compressed", "header")]
)
def test_one_flip_costs_at_most_two_percent_of_a_container(logs, tmp_path, name, kind):
    """Headers of either file and object bytes of an uncompressed file: one flip loses at
    most 2 % of a container (measured: at most 2 frames), and a frame that vanishes
    without being replaced by an altered one is always recorded as damage."""
    _, raw, truth = logs[name]
    rng = np.random.default_rng(11)
    pos = _positions(raw, kind)
    worst = 0
    for i in rng.choice(len(pos), size=30, replace=False):
        got, r = _read(_flip(tmp_path, raw, pos[i], int(rng.integers(1, 256))))
        lost = sum((truth - got).values())
        altered = sum((got - truth).values())
        worst = max(worst, lost)
        assert lost <= BUDGET, (pos[i], lost, r.damage)
        if lost > altered:
            assert r.damage, (pos[i], lost)
    assert worst <= 2


def test_flip_in_compressed_bytes_stays_inside_its_container(logs, tmp_path):
    """Inside compressed bytes (docs/edges.md): every frame of the other containers is
    kept, every changed read is recorded, and a bad Adler-32 alone drops nothing (a
    damaged trailer byte is named as the repair)."""
    _, raw, truth = logs["compressed"]
    cont = _containers(raw)
    # frames per container, from the pristine uncompressed stream
    rng = np.random.default_rng(12)
    for _ in range(12):
        c = int(rng.integers(len(cont)))
        start, size = cont[c]
        pos = int(rng.integers(start + 32, start + size))
        got, r = _read(_flip(tmp_path, raw, pos, int(rng.integers(1, 256))))
        lost = sum((truth - got).values())
        assert lost <= PER_CONTAINER + 1, (pos, lost)
        if got != truth:
            assert r.damage, pos
    start, size = cont[0]
    got, r = _read(_flip(tmp_path, raw, start + size - 1, 0x5A))  # Adler-32 byte
    assert got == truth
    assert [d["kind"] for d in r.damage] == ["repaired"]
    assert f"file byte {start + size - 1}" in r.damage[0]["why"]
    assert "Adler-32 trailer" in r.damage[0]["why"]


def test_inflate_keeps_every_byte_before_the_error():
    """Output before a deflate error or a cut is real data and is kept."""
    data = b"".join(int(k).to_bytes(4, "little") * 3 for k in range(20000))
    z = zlib.compress(data)
    got, err, gap = _inflate(z[: len(z) // 2])
    assert gap and err == "the compressed stream ends early"
    assert len(got) > len(data) // 3 and data.startswith(got)
    got, err, gap = _inflate(z)
    assert got == data and err is None and not gap


def test_damage_reaches_the_frame_accounting(logs, tmp_path):
    """The damage is counted in what read_frames returns (and refused with --strict)."""
    from fdi.errors import ReplayError

    _, raw, _ = logs["plain"]
    start, _ = _containers(raw)[0]
    q = _flip(tmp_path, raw, start + 32 + 48 * 5 + 8, 0x40)  # an object's size field
    frames, acct = read_frames(q, progress=False)
    assert len(frames.t) >= N - 2
    assert acct.errors and acct.errors[0]["kind"] == "resync"
    with pytest.raises(ReplayError, match=q.name):
        read_frames(q, strict=True, progress=False)


# ----------------------------------------------------------------- repair by search


def _compressed_flips(raw: bytes, seed: int, n: int) -> list[tuple[int, int]]:
    """Seeded (file byte, xor) flips inside the compressed bytes of the containers."""
    rng = np.random.default_rng(seed)
    cont = _containers(raw)
    out = []
    for _ in range(n):
        start, size = cont[int(rng.integers(len(cont)))]
        out.append((int(rng.integers(start + 32, start + size)), int(rng.integers(1, 256))))
    return out


def test_flip_in_compressed_bytes_is_repaired_to_the_exact_frames(logs, tmp_path):
    """A flip that breaks the objects or the deflate stream is found and undone (replay.
    blf_repair): every original frame comes back, and the one damage record, of kind
    ``repaired``, names the byte and both values. A flip that changes only a frame's
    value (its objects stay valid, only the Adler-32 disagrees) is not searched for and
    costs at most 2 % of a container unless a time stamp goes back or a frame's key
    becomes rare (then it is searched too, tests below). Measured (studies/blf_flips.py):
    166 of 200 flips are repaired."""
    _, raw, truth = logs["compressed"]
    repaired = 0
    for pos, x in _compressed_flips(raw, 21, 16):
        got, r = _read(_flip(tmp_path, raw, pos, x))
        kinds = [d["kind"] for d in r.damage]
        if kinds == ["repaired"]:
            repaired += 1
            assert got == truth, pos
            why = r.damage[0]["why"]
            assert f"file byte {pos}" in why
            assert f"read 0x{raw[pos] ^ x:02x}; 0x{raw[pos]:02x}" in why
        else:
            assert "objects are all valid" in r.damage[0]["why"], (pos, r.damage[:2])
            assert sum((truth - got).values()) <= BUDGET, pos
    assert repaired >= 10


@pytest.mark.parametrize("where", [0, 1, 5, 40])
def test_flip_in_the_zlib_and_block_headers_is_repaired(logs, tmp_path, where):
    """The zlib header (bytes 0–1) and the first dynamic-Huffman block header: the
    damage produces no output before zlib fails, and is still found."""
    _, raw, truth = logs["compressed"]
    start, _ = _containers(raw)[1]
    pos = start + 32 + where
    got, r = _read(_flip(tmp_path, raw, pos, 0x24))
    assert got == truth
    assert [d["kind"] for d in r.damage] == ["repaired"]
    assert f"file byte {pos}" in r.damage[0]["why"]


def _two_flips(tmp_path: Path, raw: bytes, containers: list[int]) -> Path:
    """Two flips 300 bytes apart in each of ``containers``: no one byte repairs them."""
    bad = bytearray(raw)
    cont = _containers(raw)
    for c in containers:
        start, size = cont[c]
        bad[start + size // 3] ^= 0x55
        bad[start + size // 3 + 300] ^= 0x33
    q = tmp_path / "two.blf"
    q.write_bytes(bytes(bad))
    return q


def test_unrepairable_damage_falls_back_to_resync(logs, tmp_path, monkeypatch):
    """Two damaged bytes in one container: the search finds no repair within its budget
    and the reader keeps exactly what it keeps without a search (the frames inflated
    before the damage, the valid objects after it); the record says so."""
    import replay.blf as blf

    _, raw, truth = logs["compressed"]
    q = _two_flips(tmp_path, raw, [0])
    monkeypatch.setattr(blf, "REPAIR_BUDGET", 3000)
    got, r = _read(q)
    assert "no one-byte repair found" in r.damage[0]["why"]
    assert "budget spent" in r.damage[0]["why"]
    assert all(d["kind"] != "repaired" for d in r.damage)
    monkeypatch.setattr(blf, "REPAIR_BUDGET", 0)
    without, r0 = _read(q)
    assert "no repair searched" in r0.damage[0]["why"]
    assert got == without
    assert 0 < sum((truth - got).values()) <= PER_CONTAINER


def test_repair_budget_bounds_the_search(logs, tmp_path, monkeypatch):
    """The trials are bounded per container and per file: with three unrepairable
    containers and a file budget of 1.5 containers, the third is not searched."""
    import time

    import replay.blf as blf

    _, raw, _ = logs["compressed"]
    q = _two_flips(tmp_path, raw, [0, 1, 2])
    monkeypatch.setattr(blf, "REPAIR_BUDGET", 2000)
    monkeypatch.setattr(blf, "REPAIR_FILE_BUDGET", 3000)
    t0 = time.perf_counter()
    _, r = _read(q)
    elapsed = time.perf_counter() - t0
    notes = [d["why"] for d in r.damage if "damaged compressed container" in d["why"]]
    assert len(notes) == 3
    assert "no one-byte repair found" in notes[0] and "budget spent" in notes[0]
    assert "no one-byte repair found" in notes[1] and "budget spent" in notes[1]
    assert "no repair searched" in notes[2]
    assert r._repair_left <= 0
    assert elapsed < 10.0  # 3000 trials of about 10 us, with a wide margin for a loaded machine


def test_repair_reaches_the_frame_accounting(logs, tmp_path):
    """A repaired container is a damage record of kind ``repaired`` in what read_frames
    returns, every frame is there, and --strict still refuses the file."""
    from fdi.errors import ReplayError

    _, raw, _ = logs["compressed"]
    start, _ = _containers(raw)[1]
    q = _flip(tmp_path, raw, start + 32 + 40, 0x24)
    frames, acct = read_frames(q, progress=False)
    assert len(frames.t) == N
    assert [e["kind"] for e in acct.errors] == ["repaired"]
    with pytest.raises(ReplayError, match="repaired"):
        read_frames(q, strict=True, progress=False)


@pytest.mark.parametrize(("pos", "x"), [(68727, 176), (62507, 146), (63223, 11)])
def test_flip_that_only_moves_a_time_stamp_back_is_repaired(logs, tmp_path, pos, x):
    """A flip whose objects all stay valid (only the Adler-32 disagrees) but that puts a
    time stamp out of order: the time order locates the damage, the Adler-32 and size
    accept the repair. The flips were picked from seeded flips of this log; the test
    first checks they still have that effect."""
    from replay.blf import _next_in_time, _next_object
    from replay.blf_repair import walk

    _, raw, truth = logs["compressed"]
    start, size = next((s, n) for s, n in _containers(raw) if s + 32 <= pos < s + n)
    bad = bytearray(raw[start + 32 : start + size])
    bad[pos - start - 32] ^= x
    with pytest.raises(zlib.error, match="incorrect data check"):
        zlib.decompress(bytes(bad))
    out = zlib.decompressobj().decompress(bytes(bad[:-4]))
    first = out.find(b"LOBJ")
    assert not walk(out, first, _next_object)[1], "the flip no longer keeps the objects valid"
    assert walk(out, first, _next_in_time)[1], "the flip no longer moves a time stamp back"
    got, r = _read(_flip(tmp_path, raw, pos, x))
    assert got == truth
    assert [d["kind"] for d in r.damage] == ["repaired"]
    assert f"file byte {pos}" in r.damage[0]["why"]


@pytest.mark.parametrize(("pos", "x"), [(61918, 200), (1277, 78), (3663, 138)])
def test_flip_that_only_changes_frame_keys_is_repaired(logs, tmp_path, pos, x):
    """A flip whose objects all stay valid and in time order (only the Adler-32
    disagrees) but that changes the identifier, channel, DLC or flags of many frames
    through deflate's back-references (measured: hundreds of frames lost without a
    search): the first frame whose key, or pair of successive keys, is rare in the file's
    intact containers and the frames before it locates the damage, the Adler-32 and size
    accept the repair. The flips were found by a seeded search of this log; the test first
    checks they still have that effect."""

    _, raw, truth = logs["compressed"]
    start, size = next((s, n) for s, n in _containers(raw) if s + 32 <= pos < s + n)
    _check_key_flip_repaired(tmp_path, raw, truth, start, size, pos, x)


def _check_key_flip_repaired(tmp_path, raw, truth, start, size, pos, x):
    """The flip at file byte ``pos`` (xor ``x``) of the container at ``start`` keeps its
    objects valid and in time order, breaks only the Adler-32 and changes the keys of more
    than BUDGET frames (checked first); the reader repairs it to the exact frames."""
    from replay.blf import _frame_keys, _next_in_time, _next_object
    from replay.blf_repair import walk

    good = zlib.decompress(raw[start + 32 : start + size])
    bad = bytearray(raw[start + 32 : start + size])
    bad[pos - start - 32] ^= x
    with pytest.raises(zlib.error, match="incorrect data check"):
        zlib.decompress(bytes(bad))
    out = zlib.decompressobj().decompress(bytes(bad[:-4]))
    first = out.find(b"LOBJ")
    assert len(out) == len(good)
    assert not walk(out, first, _next_object)[1], "the flip no longer keeps the objects valid"
    assert not walk(out, first, _next_in_time)[1], "the flip now moves a time stamp back"
    changed = sum(
        a[1] != b[1] for a, b in zip(_frame_keys(out, first), _frame_keys(good, first), strict=True)
    )
    assert changed > BUDGET, "the flip no longer changes the keys of many frames"
    got, r = _read(_flip(tmp_path, raw, pos, x))
    assert got == truth
    assert [d["kind"] for d in r.damage] == ["repaired"]
    assert f"file byte {pos}" in r.damage[0]["why"]


def test_key_flip_in_a_file_of_one_container_is_repaired(tmp_path):
    """In a file of one container, the frames of the container before the candidate are
    the reference keys: a flip that changed the keys of 1127 of its 2000 frames (found
    by a seeded search; checked first) is repaired to the exact frames."""
    p = tmp_path / "one.blf"
    raw = _write(p, -1, 2000)
    truth, r0 = _read(p)
    assert len(_containers(raw)) == 1 and not r0.damage
    start, size = _containers(raw)[0]
    _check_key_flip_repaired(tmp_path, raw, truth, start, size, 12169, 116)
