"""In-flight calibration with a prior (issue 27): a hover says what it does not know, a 90°
mounting is a rotation, a noisy axis is a finding, several flights give the turn-on spread.

Truth from the simulator (:func:`replay.imu_set.simulate_imu_set` and its truth sidecar);
the hover keeps the simulator's yaw and shrinks roll and pitch, each IMU's output rebuilt
from the sidecar's gain matrix and bias, so the relative truth is ``A = G_j·G_1⁻¹``,
``c = b_j − A·b_1``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from calibration.inflight.fit import ESTIMATED, EXCITATION_MIN, HELD, decompose, fit_inflight
from calibration.inflight.prior import Prior, nearest_mounting, signed_permutations
from replay.imu_set import ImuSetSpec, simulate_imu_set

R90Z = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
"""IMU2's axes turned 90° about z: its x reads the reference's −y."""
ROOT = Path(__file__).resolve().parents[2]


def hover(seed: int, *, imus: int = 2, mounting: np.ndarray | None = None,
          tilt: float = 0.004, noise_scale: tuple[float, ...] = (), duration_s: float = 40.0):
    """A hover-like flight: the simulator's yaw, roll and pitch shrunk by ``tilt``; IMU2
    mounted by ``mounting``. Returns the flight and the relative truth per IMU."""
    f = simulate_imu_set(ImuSetSpec(imus=imus, duration_s=duration_s, seed=seed,
                                    max_rate_dps=150.0, noise_scale=noise_scale))
    w = f.omega_true * np.array([tilt, tilt, 1.0])
    tr = f.truth["imus"]
    G = {j: np.array(tr[f"imu{j}"]["gain_matrix"]) for j in range(1, imus + 1)}
    b = {j: np.array(tr[f"imu{j}"]["bias"]) for j in range(1, imus + 1)}
    if mounting is not None:
        G[2] = mounting @ G[2]
        b[2] = mounting @ b[2]
    rng = np.random.default_rng([seed, 99])
    raw = f.raw.copy()
    sd = 2e-3 * (np.array(noise_scale) if noise_scale else np.ones(imus))
    for j in range(1, imus + 1):
        raw[:, 3 * j - 3:3 * j] = (w @ G[j].T + b[j]
                                   + sd[j - 1] * rng.standard_normal((w.shape[0], 3)))
    truth = {}
    for j in range(2, imus + 1):
        A = G[j] @ np.linalg.inv(G[1])
        truth[f"imu{j}"] = {"A": A, "c": b[j] - A @ b[1]}
    return replace(f, raw=raw, omega_true=w), truth


def _small_truth(A: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(θ, s, n) of the true A beyond the mounting R, shape (9,)."""
    p = decompose(A @ R.T)
    return np.concatenate([p["rotation"][0], p["scale"][0], p["nonorthogonality"][0]])


def test_nearest_mounting_finds_every_rotation_by_90_degrees() -> None:
    rng = np.random.default_rng(4)
    z = rng.standard_normal((500, 3))
    for R in signed_permutations():
        y = z @ R.T + 1e-2 * rng.standard_normal(z.shape) + 0.3
        assert np.array_equal(nearest_mounting(z, y)[0], R)


def test_hover_holds_what_it_does_not_excite_with_the_prior_sd() -> None:
    """Roll and pitch rates of a few deg/s: every parameter that needs them is held at the
    prior mean with the prior's sd; scale z (yaw alone) is estimated."""
    f, _ = hover(1)
    a = fit_inflight(f, check=False).alignments["imu2"]
    st = {p.name: p for p in a.parameters}
    for name in ("rotation z", "scale x", "scale y", "nonorthogonality xy"):
        assert st[name].status == HELD, name
        assert abs(st[name].value) < 1e-6
        assert st[name].sd == pytest.approx(st[name].prior_sd, rel=1e-3)
    assert st["scale z"].status == ESTIMATED
    assert st["scale z"].sd < 0.1 * st["scale z"].prior_sd
    # the file carries the prior's sd: the held parameters' uncertainty is in A_cov
    sd_A = np.sqrt(np.diag(a.A_cov)).reshape(3, 3)
    assert sd_A[0, 0] == pytest.approx(Prior().scale_sd, rel=1e-2)


@pytest.mark.slow
def test_hover_monte_carlo_estimated_within_their_sd_held_at_the_prior() -> None:
    """12 hovers (fixed seeds): the estimated parameters' errors over their reported sds are
    no larger than N(0, 1) allows (χ² upper 0.1 % bound, coverage of 2σ ≥ 90 %), the
    relative biases too; every parameter no excited axis informs stays at the prior mean
    with the prior's sd."""
    z, held_ok = [], []
    for seed in range(12):
        f, truth = hover(100 + seed, duration_s=15.0)
        a = fit_inflight(f, check=False, time_offset=False).alignments["imu2"]
        true = _small_truth(truth["imu2"]["A"], a.mounting)
        for k, p in enumerate(a.parameters):
            if p.status == ESTIMATED:
                z.append((p.value - true[k]) / p.sd)
            elif p.excitation < EXCITATION_MIN:       # no excited axis informs it at all
                held_ok.append(abs(p.sd / p.prior_sd - 1) < 0.05 and abs(p.value) < 1e-6)
        zc = (a.c - truth["imu2"]["c"]) / np.sqrt(np.diag(a.c_cov))
        z.extend(zc.tolist())
    z = np.array(z)
    assert len(z) > 12 * 4 and held_ok and all(held_ok)
    assert float(np.sum(z**2)) < stats.chi2.ppf(0.999, len(z))
    assert np.mean(np.abs(z) < 2) >= 0.90


def test_a_90_degree_mounting_is_a_rotation_not_a_scale() -> None:
    f, truth = hover(7, mounting=R90Z, tilt=1.0)
    a = fit_inflight(f, check=False).alignments["imu2"]
    assert np.array_equal(a.mounting, R90Z)
    parts = a.parts()
    assert np.all(np.abs(parts["scale"][0]) < 0.05)          # not −1 (−1e6 ppm)
    true = _small_truth(truth["imu2"]["A"], R90Z)
    est = np.concatenate([parts["rotation"][0], parts["scale"][0],
                          parts["nonorthogonality"][0]])
    sd = np.concatenate([parts["rotation"][1], parts["scale"][1], parts["nonorthogonality"][1]])
    assert np.all(np.abs(est - true) < 4 * sd)


def test_a_noisy_axis_is_a_finding_not_a_refusal() -> None:
    """Three IMUs, IMU3's x (and all its axes) six times noisier: a finding names it."""
    f, _ = hover(3, imus=3, tilt=1.0, noise_scale=(1.0, 1.0, 6.0))
    fit = fit_inflight(f, check=False)
    named = {(x.imu, x.axis) for x in fit.findings}
    assert ("imu3", "x") in named and not any(g != "imu3" for g, _ in named)
    x = next(x for x in fit.findings if x.imu == "imu3")
    assert 3.0 < x.noise_sd / x.others_sd < 12.0
    assert "deg/s vibration against" in x.text()


def _rimu(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rimu", *args], capture_output=True,
                          text=True, cwd=ROOT)


def test_cli_window_and_several_flights_write_the_turn_on_spread(tmp_path: Path) -> None:
    """Two power-ups of one set (biases drawn anew, the gains the same): the joint file has
    each sensor's bias_turn_on_sd and each flight's own values; --window cuts a record."""
    from fdi.calfile import load_calibration
    from replay.flight_io import save_flight_dir

    dirs = []
    for k, seed in enumerate((11, 12)):
        f = simulate_imu_set(ImuSetSpec(imus=2, duration_s=12, seed=5, max_rate_dps=150))
        rng = np.random.default_rng(seed)
        raw = f.raw + 0.01 * rng.standard_normal((1, f.raw.shape[1]))   # turn-on bias
        d = tmp_path / f"f{k}"
        save_flight_dir(replace(f, raw=raw), d)
        dirs.append(str(d))
    out = tmp_path / "joint.json"
    r = _rimu("calibrate", "in-flight", *dirs, "--out", str(out), "--window", "1:11")
    assert r.returncode == 0, r.stderr
    assert "bias_turn_on_sd" in r.stdout
    cal = load_calibration(out)
    sds = [c.bias_turn_on_sd for c in cal.gyro.sensors]
    assert all(s is not None and s >= 0 for s in sds)
    doc = json.loads(out.read_text())
    flights = doc["extra"]["inflight"]["flights"]
    assert [v["source"] for v in flights] == dirs
    assert doc["extra"]["inflight"]["window_s"] == [1.0, 11.0]
    r = _rimu("calibrate", "in-flight", dirs[0], "--out", str(tmp_path / "x.json"),
              "--window", "20:30")
    assert r.returncode == 2 and "holds no sample" in r.stderr


def test_bias_turn_on_sd_round_trips_and_a_bad_one_is_named(tmp_path: Path) -> None:
    from fdi.calfile import load_calibration
    from fdi.errors import FileFormatError
    from fdi.units import DPH

    f, _ = hover(2, tilt=1.0, duration_s=10.0)
    from calibration.inflight.calfile import calibration_from_fit

    cal = calibration_from_fit(fit_inflight(f, check=False), f, tails=False,
                               turn_on_sd={"imu1": np.full(3, 50 * DPH),
                                           "imu2": np.full(3, 80 * DPH)})
    cal.save(tmp_path / "c.json")
    back = load_calibration(tmp_path / "c.json")
    got = [c.bias_turn_on_sd / DPH for c in back.gyro.sensors]
    assert got[:3] == pytest.approx([50.0] * 3) and got[3] == pytest.approx(80.0, rel=0.05)
    doc = json.loads((tmp_path / "c.json").read_text())
    assert "bias_turn_on_sd" in doc["sensors"]["gyro"][0]
    doc["sensors"]["gyro"][1]["bias_turn_on_sd"] = -1.0
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=r"bias_turn_on_sd.*>= 0"):
        load_calibration(tmp_path / "bad.json")
    del doc["sensors"]["gyro"][1]["bias_turn_on_sd"]
    doc["extra"]["inflight"]["imus"]["imu2"]["parameters"][0]["status"] = "guessed"
    (tmp_path / "bad2.json").write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=r"parameters.*status"):
        load_calibration(tmp_path / "bad2.json")
