"""Static calibration of several IMUs at rest (calibration.inflight.static, rimu calibrate
static) on synthetic sets with known rotations, biases and drifts; the 4xMPU9250 chain
on the shared recording when it is there."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibration.inflight.static import attribute_drift, calibrate_static
from fdi.errors import CalibrationError
from fdi.units import DPS, G0
from replay.flight_data import AuxChannels, Flight
from replay.flight_io import save_flight_dir
from rimu.cli import main

FS = 40.0
ROT = [Rotation.identity(), Rotation.from_rotvec([0.3, -0.2, 0.5]),
       Rotation.from_rotvec([-0.1, 0.4, 2.0])]


def _set(seed: int = 0, n: int = 24000, drift: dict[int, np.ndarray] | None = None,
         shared: bool = True) -> Flight:
    """Three IMUs at rest; IMU k reads v_k = R_kᵀ·v_body; gravity in every accelerometer,
    bursts of a shared rotation about one body axis, white gyro noise 0.1 deg/s, and
    ``drift`` (body frame, rad/s over the record) added to the chosen IMUs."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    axis = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    burst = np.zeros(n)
    if shared:
        for c in rng.integers(0, n - 200, 40):
            burst[c:c + 60] += 0.02 * np.sin(np.linspace(0, 6 * np.pi, 60))
    g_body = np.array([0.0, 0.0, -G0])
    gyro, acc = [], []
    for k, R in enumerate(ROT):
        M = R.as_matrix().T                        # body → IMU k
        w = np.outer(burst, axis)
        if drift and k in drift:
            w = w + np.outer(t / t[-1], drift[k])
        gyro.append(w @ M.T + rng.normal(0, 0.1 * DPS, (n, 3)) + 0.01 * (k + 1))
        acc.append(np.tile(M @ -g_body, (n, 1)) + rng.normal(0, 0.05, (n, 3)))
    raw = np.hstack(gyro)
    av = np.hstack(acc)
    names = tuple(f"imu{k + 1}.{a}" for k in range(3) for a in "xyz")
    aux = AuxChannels(("accel",) * 9, names, tuple(f"imu{k + 1}" for k in range(3)
                                                      for _ in range(3)), av,
                      np.ones_like(av, bool))
    return Flight(t=t, raw=raw, valid=np.ones_like(raw, bool), sample_rate_hz=FS,
                  sensor_names=names, raw_unit="rad/s", source="synthetic-static",
                  kind="gyro", imu=tuple(f"imu{k + 1}" for k in range(3) for _ in range(3)),
                  aux=aux)


def test_rotations_and_biases_within_their_sd() -> None:
    cal = calibrate_static(_set())
    doc = cal.extra["static"]
    assert doc["alignment_full"]
    for k in (2, 3):
        est = np.radians(doc["imus"][f"imu{k}"]["rotation_deg"])
        sd = np.radians(doc["imus"][f"imu{k}"]["rotation_deg_sd"])
        err = (Rotation.from_rotvec(est) * ROT[k - 1].inv()).magnitude()
        assert err < 4 * np.linalg.norm(sd) + 1e-3, (err, sd)
    b = np.array(doc["bias_dps"]) * DPS
    want = np.repeat([0.01, 0.02, 0.03], 3)
    assert np.all(np.abs(b - want) < 4 * np.array(doc["bias_dps_sd"]) * DPS + 1e-4)


def test_gravity_alone_leaves_the_rotation_about_it_unobservable() -> None:
    cal = calibrate_static(_set(shared=False))
    doc = cal.extra["static"]
    assert not doc["alignment_full"]
    assert any("not observable" in n for n in doc["notes"])


def test_drift_of_the_reference_is_named_as_the_reference_s() -> None:
    d = np.array([0.0, 0.0, 0.03 * DPS * 5])          # reference drifts 0.15 deg/s about z
    cal = calibrate_static(_set(drift={0: d}))
    a = cal.extra["static"]["drift_attribution"]
    assert a["common_p"] < 1e-6 and a["consistent_p"] > 1e-3
    assert "imu1's own drift" in a["statement"]
    assert np.asarray(a["common"]) @ np.array([0, 0, 1]) == pytest.approx(-0.15, abs=0.03)


def test_drift_of_one_other_imu_is_its_own() -> None:
    cal = calibrate_static(_set(drift={2: np.array([0.15 * DPS, 0.0, 0.0])}))
    a = cal.extra["static"]["drift_attribution"]
    assert a["own"]["imu3"]["p_value"] < 1e-6 and a["own"]["imu2"]["p_value"] > 1e-3
    assert a["statement"].startswith("imu3 drifts relative to imu1 and to imu2")


def test_attribute_drift_by_hand() -> None:
    c = np.array([1.0, -2.0, 0.5])
    rel = {"b": c.copy(), "c": c.copy()}
    cov = {"b": np.eye(3) * 0.01, "c": np.eye(3) * 0.01}
    a = attribute_drift(rel, cov, "a")
    np.testing.assert_allclose(a["common"], c)
    np.testing.assert_allclose(a["common_sd"], np.sqrt(0.005))
    assert a["consistent_chi2"] == pytest.approx(0.0) and a["consistent_dof"] == 3
    assert "a's own drift" in a["statement"]


def test_moving_set_is_refused() -> None:
    f = _set(n=4000)
    raw = f.raw + np.sin(np.arange(4000) / 10.0)[:, None]
    with pytest.raises(CalibrationError, match="moving"):
        calibrate_static(Flight(t=f.t, raw=raw, valid=f.valid, sample_rate_hz=FS,
                                sensor_names=f.sensor_names, raw_unit="rad/s",
                                source="m", kind="gyro", imu=f.imu, aux=f.aux))


def test_cli_static_calibration_then_diagnose_names_the_drift(tmp_path: Path, capsys) -> None:
    d = tmp_path / "f"
    save_flight_dir(_set(drift={1: np.array([0.2 * DPS, 0.0, 0.0])}), d)
    assert main(["calibrate", "static", str(d), "--out", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out
    assert "static calibration against imu1" in out
    # the range the samples covered, as the file states it (rimu tune corrects inside it)
    from fdi.calfile import load_calibration

    vr = load_calibration(tmp_path / "c.json").gyro.validated_rate
    line = next(x for x in out.splitlines() if x.startswith("covered range"))
    assert " / ".join(f"{v / DPS:.2f}" for v in vr) in line and "tune" in line
    assert main(["diagnose", str(d), "--cal", str(tmp_path / "c.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    found = {e["imu"] for e in doc["effects"] if e["name"] in ("bias_drift",
                                                                "slow_bias_change")}
    assert "imu2" in found
    assert doc["calibration_kind"] == "static"
    assert doc["drift_attribution"]["statement"]


def _mpu() -> Path | None:
    root = Path(os.environ.get("RIMU_SHARED_DATA",
                               Path(__file__).resolve().parents[2] / ".." / "shared" / "data"))
    p = root / "multi_imu_4x_mpu9250"
    return p if all((p / f"imu{k}_raw.mat").is_file() for k in range(1, 5)) else None


@pytest.mark.slow
@pytest.mark.skipif(_mpu() is None, reason="4xMPU9250 recording not in ../shared/data")
def test_mpu9250_chain_names_the_drift_and_whose_it_is(tmp_path: Path, capsys) -> None:
    """ingest → calibrate static → characterise → diagnose on the 16-min static set."""
    p = _mpu()
    d = tmp_path / "m4"
    assert main(["ingest", *(str(p / f"imu{k}_raw.mat") for k in range(1, 5)),
                 "--out", str(d)]) == 0
    assert main(["calibrate", "static", str(d), "--out", str(tmp_path / "c.json")]) == 0
    out = capsys.readouterr().out
    assert "imu1's own" in out                         # the reference's drift, named
    assert main(["characterise", str(d), "--json"]) == 0
    ch = json.loads(capsys.readouterr().out)
    assert any(any(r["drift_significant"]) for r in ch["imus"].values())
    assert main(["diagnose", str(d), "--cal", str(tmp_path / "c.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    drift = [e for e in doc["effects"] if e["name"] in ("bias_drift", "slow_bias_change")]
    assert drift and all(e["p_value"] < 1e-6 for e in drift)
    assert "imu1" in doc["drift_attribution"]["statement"]


def test_static_calibration_needs_two_imu_triads():
    """One IMU, or gyros not in triads: one error naming what is needed (Flight.imu_triads,
    shared with the flight diagnosis)."""
    from fdi.errors import ConfigError

    N = 200
    one = Flight(t=np.arange(N) / 50.0, raw=np.zeros((N, 3)), valid=np.ones((N, 3), bool),
                 sensor_names=("imu1.x", "imu1.y", "imu1.z"), sample_rate_hz=50.0,
                 source="one.csv", imu=("imu1",) * 3)
    with pytest.raises(ConfigError, match=r"one\.csv: static calibration needs two or more "
                                          r"IMU groups of three gyros"):
        calibrate_static(one)


def test_a_knock_is_left_out_and_marked_beyond_the_range() -> None:
    """A knock on the bench (every accelerometer jumps, every gyro turns for two samples):
    the static calibration leaves its samples out of the noise, the residual models and the
    range (a note says how many), and the monitor's envelope marks it beyond the covered
    jolt (RANGE) while the rest of the record stays inside."""
    from dataclasses import replace

    from fdi.envelope import RANGE
    from replay.envelope import flight_envelope

    f = _set(seed=4, shared=False)
    k = 12000
    raw, acc = f.raw.copy(), f.aux.values.copy()
    raw[k:k + 2] += 0.05                               # rad/s on every gyro axis
    acc[k:k + 2] += 2.0                                # m/s² on every accelerometer axis
    f = replace(f, raw=raw, aux=replace(f.aux, values=acc))
    cal = calibrate_static(f)
    note = [n for n in cal.extras.static.notes if "near shocks" in n]
    assert note, cal.extras.static.notes
    pad = round(0.5 * FS)
    assert note[0].startswith(f"{2 + 2 * pad} of {raw.shape[0]} samples"), note[0]
    jolt = cal.gyro.validated_jolt
    assert jolt is not None and jolt < 1.0, jolt
    env = flight_envelope(f, cal)
    assert (env[k:k + 3] & RANGE).all(), env[k - 2:k + 4]
    assert np.mean(env != 0) < 0.01
