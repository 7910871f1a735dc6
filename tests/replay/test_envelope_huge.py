"""replay.envelope on huge and non-finite numbers (issue 30): no warning, no exception;
the samples are marked out of the envelope and the summary is still given."""

from __future__ import annotations

import warnings

import numpy as np

from replay.envelope import envelope_summary, flight_envelope, flying_mask, uncalibrated_summary
from replay.flight_data import Flight
from studies.synthetic import synthetic_calibration

N = 400


def _flight(raw: np.ndarray, unit: str) -> Flight:
    return Flight(
        t=np.arange(N) / 100.0,
        raw=raw,
        valid=np.ones((N, 6), bool),
        sample_rate_hz=100.0,
        sensor_names=tuple(f"s{i}" for i in range(6)),
        raw_unit=unit,
        imu=("a", "a", "a", "b", "b", "b"),
    )


def test_huge_values_give_codes_not_warnings():
    raw = np.random.default_rng(0).normal(0.0, 0.01, (N, 6))
    raw[100:200] = 1e308
    raw[250, 2] = -1e308
    raw[300, 0] = np.inf
    raw[310, 1] = np.nan
    everywhere = _flight(np.full((N, 6), 1e308), "LSB")
    cal = synthetic_calibration("cone6", seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fly = flying_mask(_flight(raw, "rad/s"))
        doc = uncalibrated_summary(_flight(raw, "rad/s"))
        codes = flight_envelope(everywhere, cal)
        whole = envelope_summary(everywhere, codes)
    assert fly[100:200].all()
    assert doc is not None and doc["marked_samples"] >= 100
    assert (codes != 0).all() and whole["marked_samples"] == N
