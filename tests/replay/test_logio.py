"""CAN logs: write/read round trip per format, and every frame accounted for under corruption."""

import re

import numpy as np
import pytest

from fdi.calfile import Calibration, SensorCal, SensorSet
from fdi.errors import FileFormatError, ReplayError
from fdi.geometry import load_configuration
from fdi.units import DPH, DPS
from replay.can_files import truth_path
from replay.can_write import write_flight_log
from replay.crc import crc8_j1850
from replay.faults import Fault
from replay.flight import simulate_flight
from replay.logio import read_log


def make_cal(config="cone6", *, noise_dps=0.01, sf=0.01 * DPS, err=2e-4, seed=0):
    """A calibration with misalignment, bias and uncertainty (raw unit mV)."""
    cfg = load_configuration(config)
    rng = np.random.default_rng(seed)
    sens = []
    for i in range(cfg.n):
        h = cfg.H[i] + 1e-3 * rng.standard_normal(3)
        sens.append(SensorCal(
            name=cfg.sensor_names[i], axis=h / np.linalg.norm(h), axis_nominal=cfg.H[i],
            scale_factor=sf * (1 + 0.01 * i), scale_factor_sd=err * sf,
            bias=10 * DPH * rng.standard_normal(), bias_sd=(1 + i) * DPH,
            input_error_cov=np.diag([1.0, 2.0, 3.0]) * err ** 2,
            misalignment_sd=np.full(2, err), raw_unit="mV",
            scale_factor_unit="mV/(deg/s)", bias_unit="deg/h"))
    A = rng.standard_normal((cfg.n, cfg.n)) * 0.2 + np.eye(cfg.n)
    cov = (noise_dps * DPS) ** 2 * (A @ A.T) / np.mean(np.diag(A @ A.T))
    return Calibration(cfg.name, {"gyro": SensorSet("gyro", tuple(sens), cov)}, 100.0)


CAL = make_cal()


@pytest.fixture(scope="module")
def flight():
    f = simulate_flight(CAL, 3.0, seed=2, faults=(Fault("dropout", 4, 0.0, 1.0, 0.05,
                                                        "dropout:4:0:1"),))
    return f


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".csv", ".trc"])
def test_round_trip_every_format(tmp_path, flight, suffix):
    p = tmp_path / f"f{suffix}"
    write_flight_log(flight, p)
    assert truth_path(p).is_file()
    f2, frames = read_log(p, CAL, progress=False)
    n_frames = int(flight.valid.sum())
    assert frames["read"] == n_frames and frames["used"] == n_frames and frames["balanced"]
    assert frames["rejected"] == {} and frames["errors"] == []
    np.testing.assert_array_equal(f2.valid, flight.valid, err_msg=f"{suffix}: valid")
    ok = flight.valid
    np.testing.assert_allclose(f2.raw[ok], flight.raw[ok], rtol=6e-8, err_msg=f"{suffix}: raw")
    # dropout: missing, never zero
    assert np.all(np.isnan(f2.raw[~ok]))
    np.testing.assert_allclose(f2.t, flight.t, atol=1e-6, err_msg=f"{suffix}: sample times")
    np.testing.assert_array_equal(f2.omega_true, flight.omega_true)
    assert [f.kind for f in f2.faults] == ["dropout"]


def _rewrite_candump(lines, *, n):
    """Corrupt a candump log (lines in time order, n frames per sample); return new lines."""
    pat = re.compile(r"^\((?P<t>[\d.]+)\) (?P<ch>\S+) (?P<id>[0-9A-F]+)#(?P<d>[0-9A-F]*)(?P<r>.*)$")

    def parts(i):
        return pat.match(lines[i]).groupdict()

    def line(g):
        return f"({g['t']}) {g['ch']} {g['id']}#{g['d']}{g['r']}"

    out = list(lines)
    # (sample k, sensor i) -> line index k*n+i; corrupt distinct messages, far apart
    crc_bad = [(20, 0), (40, 1), (60, 2), (80, 3), (100, 4)]
    short = [(30, 5), (70, 0), (110, 1)]
    jump = [(50, 2), (150, 5)]
    ooo = (200, 0)
    for k, i in crc_bad:
        g = parts(k * n + i)
        b = bytearray.fromhex(g["d"])
        b[1] ^= 0x10
        g["d"] = b.hex().upper()
        out[k * n + i] = line(g)
    for k, i in short:
        g = parts(k * n + i)
        g["d"] = g["d"][:12]
        out[k * n + i] = line(g)
    for k, i in jump:
        g = parts(k * n + i)
        b = bytearray.fromhex(g["d"])
        b[6] = (b[6] & 0x0F) | ((((b[6] >> 4) + 5) % 16) << 4)
        b[7] = crc8_j1850(bytes(b[:7]))
        g["d"] = b.hex().upper()
        out[k * n + i] = line(g)
    g = parts(ooo[0] * n + ooo[1])
    g["t"] = f"{float(g['t']) - 0.015:.6f}"
    out[ooo[0] * n + ooo[1]] = line(g)
    # insertions (from the back so indices stay valid)
    t5 = parts(5 * n)["t"]
    ins = [
        (250 * n, lines[249 * n]),                            # a repeated frame
        (240 * n, f"({t5}) can0 7FF#0102"),                   # unknown ids
        (230 * n, f"({t5}) can0 1FFFFFFF#00"),
        (220 * n, f"({t5}) can0 055#"),
        (210 * n, f"({t5}) can0 0A0#AABBCCDD"),
        (190 * n, "this is not a CAN frame"),                 # garbage lines
        (180 * n, "(12.5) can0 XYZ#0011"),
        (170 * n, "(not-a-time) can0 101#0011223344556677"),
        (160 * n, f"({t5}) can0 101#R"),                      # a remote frame
    ]
    for idx, text in sorted(ins, reverse=True):
        out.insert(idx, text)
    expect = {"crc": 5, "wrong_length": 3, "counter_jump": 4, "out_of_order": 1,
              "counter_repeat": 1, "unknown_id": 4, "garbage_line": 3, "remote_frame": 1}
    return out, expect, crc_bad + short + jump + [ooo]


def test_corrupted_candump_every_frame_accounted(tmp_path):
    f = simulate_flight(CAL, 3.0, seed=3)
    n = f.n
    p = tmp_path / "clean.log"
    write_flight_log(f, p)
    lines = p.read_text().splitlines()
    new, expect, bad = _rewrite_candump(lines, n=n)
    q = tmp_path / "bad.log"
    q.write_text("\n".join(new) + "\n")
    f2, fr = read_log(q, CAL, progress=False)
    assert fr["rejected"] == expect
    assert fr["read"] == len(lines) + 9
    assert fr["balanced"] and fr["read"] == fr["used"] + sum(fr["rejected"].values())
    assert fr["used"] == len(lines) - 13  # crc 5, length 3, jump 2 + 2 neighbours, ooo 1
    # counter gaps left by frames rejected before the counter check (crc, length, order)
    assert fr["lost_frames"] == 9
    garbage = [e for e in fr["errors"] if e["kind"] == "garbage_line"]
    assert [e["where"] for e in garbage] == [f"line {i}" for i in
                                            sorted(new.index(x) + 1 for x in new
                                                   if x.startswith(("this", "(12.5)", "(not")))]
    # rejected values are missing (valid False, NaN), the rest equal the flight
    missing = set(bad) | {(51, 2), (151, 5)}
    assert f2.raw.shape == f.raw.shape
    for k, i in missing:
        assert not f2.valid[k, i] and np.isnan(f2.raw[k, i]), f"sample {k} sensor {i + 1}"
    mask = np.ones_like(f.valid)
    for k, i in missing:
        mask[k, i] = False
    np.testing.assert_array_equal(f2.valid, mask)
    np.testing.assert_allclose(f2.raw[mask], f.raw[mask], rtol=6e-8)


def test_strict_mode_raises_on_garbage_and_corrupt_frames(tmp_path):
    f = simulate_flight(CAL, 1.0, seed=4)
    p = tmp_path / "a.log"
    write_flight_log(f, p)
    lines = p.read_text().splitlines()
    q = tmp_path / "g.log"
    q.write_text("\n".join([*lines[:10], "garbage", *lines[10:]]) + "\n")
    with pytest.raises(ReplayError, match=r"g\.log:11"):
        read_log(q, CAL, strict=True, progress=False)
    _, fr = read_log(q, CAL, progress=False)
    assert fr["rejected"] == {"garbage_line": 1} and fr["used"] == len(lines)
    b = tmp_path / "c.log"
    bad = lines[20][:-4] + ("00" if lines[20][-4:-2] != "00" else "11") + lines[20][-2:]
    b.write_text("\n".join([*lines[:20], bad, *lines[21:]]) + "\n")
    with pytest.raises(ReplayError, match="1 crc"):
        read_log(b, CAL, strict=True, progress=False)


def test_asc_garbage_lines_counted(tmp_path):
    f = simulate_flight(CAL, 1.0, seed=5)
    p = tmp_path / "a.asc"
    write_flight_log(f, p)
    lines = p.read_text().splitlines()
    first = next(i for i, x in enumerate(lines) if " Rx " in x)
    junk = ["@@@ garbage @@@", "1.2345 1 101 Rx d 8 ZZ 00 00 00 00 00 00 00"]
    new = [*lines[:first + 7], *junk, *lines[first + 7:first + 30], "", "// a comment",
           "12345", *lines[first + 30:]]
    q = tmp_path / "g.asc"
    q.write_text("\n".join(new) + "\n")
    _, fr = read_log(q, CAL, progress=False)
    n_frames = int(f.valid.sum())
    assert fr["rejected"] == {"garbage_line": 3}, fr
    assert fr["used"] == n_frames and fr["balanced"]


def test_truncated_blf_reported_and_kept(tmp_path):
    f = simulate_flight(CAL, 4.0, seed=6)
    p = tmp_path / "a.blf"
    write_flight_log(f, p)
    b = p.read_bytes()
    q = tmp_path / "cut.blf"
    q.write_bytes(b[: len(b) // 2])
    truth_path(p).rename(truth_path(q))
    f2, fr = read_log(q, CAL, progress=False)
    assert 0 < fr["read"] < f.valid.sum() and fr["balanced"]
    assert fr["errors"] and fr["errors"][0]["kind"] == "truncated"
    assert "truncated" in fr["errors"][0]["why"]
    # what was read is right
    k = f2.t.size
    ok = f2.valid
    assert ok[:-1].all()  # only the last sample may be partial
    np.testing.assert_allclose(f2.raw[ok], f.raw[:k][ok], rtol=6e-8)
    with pytest.raises(ReplayError, match="truncated"):
        read_log(q, CAL, strict=True, progress=False)


def test_corrupt_blf_container_skipped_and_reading_resumes(tmp_path):
    """Issue 10: a damaged container used to end the read (half the flight lost, exit 0).
    Now it is skipped, reading resumes at the next container, the skipped bytes are
    reported, and every frame and sample missing is counted as lost."""
    f = simulate_flight(CAL, 12.0, seed=7)  # several BLF containers
    p = tmp_path / "a.blf"
    write_flight_log(f, p)
    b = bytearray(p.read_bytes())
    b[len(b) // 2: len(b) // 2 + 64] = b"\xff" * 64
    p.write_bytes(bytes(b))
    f2, fr = read_log(p, CAL, progress=False)
    n = int(f.valid.sum())
    # since issue 30 the bytes inflated around the damage are kept and walked object by
    # object: objects decoded from the damaged bytes that look valid reach the frame
    # checks, which reject and count them (they were dropped unseen with the container)
    checks = {"unknown_id", "other_channel", "wrong_length", "crc", "counter_repeat",
              "counter_jump", "out_of_order", "duplicate", "late"}
    assert fr["balanced"] and set(fr["rejected"]) <= checks, fr["rejected"]
    assert sum(fr["rejected"].values()) < n / 3          # inside the damaged container
    err = fr["errors"][0]
    # the container's record says what failed; the skipped bytes are in the object records
    assert err["kind"] == "resync", fr["errors"]
    assert sum(e["skipped_bytes"] for e in fr["errors"]) > 0, fr["errors"]
    assert 0 < n - fr["read"] < n / 2                  # one container of three
    # every frame of the flight used or counted lost (the rejected ones are not its frames)
    assert fr["read"] - sum(fr["rejected"].values()) + fr["lost_frames"] == n
    assert f2.t.size + fr["lost_samples"] == f.t.size  # every sample delivered or lost
    assert f2.t[-1] == pytest.approx(f.t[-1], abs=1e-3), "the read went on to the end"
    k = np.rint(f2.t * CAL.sample_rate_hz).astype(int)
    np.testing.assert_allclose(f2.raw[f2.valid], f.raw[k][f2.valid], rtol=6e-8)
    with pytest.raises(ReplayError, match=r"damaged (compressed )?container"):
        read_log(p, CAL, strict=True, progress=False)


def test_random_bytes_are_not_a_blf_file(tmp_path):
    """Issue 10: random bytes with a .blf suffix said "0 frames read"."""
    p = tmp_path / "noise.blf"
    p.write_bytes(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(FileFormatError, match="not a BLF file"):
        read_log(p, CAL, progress=False)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_damage_every_line_accounted(tmp_path, seed):
    """Random damage to a candump log: every non-blank line is a frame read (used or
    rejected) and the balance holds; no exception."""
    f = simulate_flight(CAL, 1.0, seed=40 + seed)
    p = tmp_path / "a.log"
    write_flight_log(f, p)
    lines = p.read_text().splitlines()
    rng = np.random.default_rng(seed)
    out = []
    for line in lines:
        u = rng.uniform()
        if u < 0.03:      # truncate anywhere
            line = line[: rng.integers(0, len(line))]
        elif u < 0.06:    # flip a character of the payload
            j = rng.integers(len(line) - 18, len(line) - 2)
            line = line[:j] + "0123456789ABCDEF"[rng.integers(16)] + line[j + 1:]
        elif u < 0.08:    # noise line
            out.append("".join(chr(c) for c in rng.integers(32, 127, rng.integers(1, 40))))
        elif u < 0.09:    # duplicate
            out.append(line)
        out.append(line)
    q = tmp_path / "d.log"
    q.write_text("\n".join(out) + "\n")
    f2, fr = read_log(q, CAL, progress=False)
    assert fr["balanced"]
    assert fr["read"] == sum(1 for x in out if x.strip())
    assert fr["used"] <= int(f.valid.sum())
    assert f2.raw.shape[1] == f.n and np.all(np.isnan(f2.raw[~f2.valid]))
    # every value that got through equals what was sent (payload damage is caught by CRC)
    k = np.rint(f2.t * 100).astype(int)
    assert np.all(np.abs(f2.t - f.t[k]) < 1e-3)
    np.testing.assert_allclose(f2.raw[f2.valid], f.raw[k][f2.valid], rtol=6e-8)
