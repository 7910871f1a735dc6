"""Ramp of 0.05σ/s on cone6: windows vs CUSUM vs the oracle (known fault direction).

Measured, not assumed: every detector must find every ramp without an alarm before onset,
and the monitor's median delay must stay under 2× the oracle's (issue 3's aim)."""

from __future__ import annotations

import numpy as np
import pytest

from fdi.monitor import Monitor
from studies.oracle import oracle_detect
from studies.synthetic import draw_truth, raw_samples
from studies.synthetic import synthetic_calibration as synth
from thresholds import compute_thresholds

FS = 100.0


def ramp_delays(amp_dps: float, runs: int, detectors: dict) -> dict[str, np.ndarray]:
    out: dict[str, list[float]] = {k: [] for k in [*detectors, "oracle"]}
    for k in range(runs):
        cal = synth("cone6", seed=k)
        rng = np.random.default_rng(k)
        N, onset, s = 12_000, 2000, int(rng.integers(0, 6))
        t = np.arange(N) / FS
        ph = rng.uniform(0, 2 * np.pi, 3)
        fr = rng.uniform(0.05, 0.5, 3)
        om = np.deg2rad(amp_dps) / np.sqrt(3) * np.sin(2 * np.pi * fr * t[:, None] + ph)
        f = np.zeros((N, 6))
        f[onset:, s] = 0.05 * cal.gyro.noise_sd[s] * (t[onset:] - t[onset]) * rng.choice([-1, 1])
        raw = raw_samples(cal, om, seed=k + 9000, truth=draw_truth(cal, seed=k + 99), fault=f)
        for name, kw in detectors.items():
            res = Monitor(cal, compute_thresholds(cal, **kw)).run(t, raw)
            det = [e.t for e in res.events if e.type == "detected"]
            assert det and det[0] >= t[onset], (name, k, det[:1])
            out[name].append(det[0] - t[onset])
        o = oracle_detect(cal, t, raw, s + 1, t[onset])
        assert o.false_alarms == 0
        out["oracle"].append(o.delay_s)
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.slow
@pytest.mark.parametrize("amp_dps", [30.0, 300.0])
def test_ramp_windows_vs_cusum_vs_oracle(amp_dps):
    dets = {"windows": {"detector": "windows"},
            "cusum": {"detector": "cusum", "cusum_drift": 0.25},
            "both": {"detector": "both", "cusum_drift": 0.25}}
    d = ramp_delays(amp_dps, 8, dets)
    for name in dets:
        ratio = d[name] / d["oracle"]
        print(f"{amp_dps:5.0f} dps {name:8s} median delay {np.median(d[name]):6.2f} s, "
              f"oracle {np.median(d['oracle']):6.2f} s, ratio median {np.median(ratio):.2f} "
              f"max {ratio.max():.2f}")
        assert np.all(np.isfinite(d[name]))
        assert np.median(ratio) < 2.0
