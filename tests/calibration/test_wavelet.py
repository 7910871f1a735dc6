"""Wavelet denoising (seed 000: db4, 8 levels at 100 Hz ≈ 0.2 Hz)."""

import numpy as np
import pytest

from calibration.wavelet import cutoff_hz, denoise


def test_cutoff_of_level_8_at_100_hz():
    assert cutoff_hz(100.0, 8) == pytest.approx(0.1953125), "fs/2^(L+1)"


@pytest.mark.parametrize("mode", ["approx", "soft"])
def test_keeps_table_rate_sinusoid_and_removes_white_noise(mode):
    rng = np.random.default_rng(0)
    fs, N = 100.0, 3601                                      # odd length on purpose
    t = np.arange(N) / fs
    s = 0.004 * np.sin(2 * np.pi * t / 36.0 + 0.3)            # 10 deg/s turn: 0.028 Hz
    noise = rng.normal(0, 0.01, N)
    y = denoise(s + noise, mode=mode)
    assert y.shape == (N,)
    interior = slice(300, N - 300)
    err = y[interior] - s[interior]
    # white noise through a ~0.2 Hz low-pass keeps ~sqrt(0.2/50) of its sd
    assert np.std(err) < 0.01 * 0.12, f"{mode}: residual noise sd {np.std(err)}"
    # db4 is not an ideal low-pass: the A8 reconstruction of a 0.028 Hz tone is within
    # ~2 % of it (rms well below); the Earth-rate fit filters its regressors the same way.
    clean = denoise(s, mode="approx")
    np.testing.assert_allclose(clean[interior], s[interior], atol=0.02 * 0.004,
                               err_msg="a noise-free 0.028 Hz sinusoid passes (2 %)")
    assert np.sqrt(np.mean((clean[interior] - s[interior]) ** 2)) < 0.005 * 0.004


def test_columns_independent_and_short_signals():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(2000, 3))
    Y = denoise(X)
    for j in range(3):
        np.testing.assert_allclose(Y[:, j], denoise(X[:, j]), err_msg=f"column {j}")
    short = rng.normal(size=40)
    assert denoise(short).shape == (40,)                     # level reduced, no error
    with pytest.raises(ValueError):
        denoise(short, mode="hard")
