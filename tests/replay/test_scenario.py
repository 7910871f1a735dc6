"""Fault scenarios injected into a healthy recording: file format and the applied effects."""

import numpy as np
import pytest
from test_logio import CAL

from fdi.errors import FileFormatError
from replay.flight import simulate_flight
from replay.scenario import apply_faults, inject, load_scenario

SCEN = """schema = "rimu.scenario/1"
seed = 3

[[faults]]
sensor = 3
kind = "step"
size = "15sigma"
onset = 1.0
duration = 0.5

[[faults]]
spec = "ramp:2:0.05sigma/s:0.5"

[[faults]]
sensor = 5
kind = "stuck"
onset = 2.0

[[faults]]
sensor = 6
kind = "dropout"
onset = 0.2
duration = 0.1

[[faults]]
sensor = 1
kind = "noise"
size = "3x"
onset = 0.0
"""


@pytest.fixture(scope="module")
def clean():
    return simulate_flight(CAL, 3.0, seed=8)


def test_scenario_applies_each_fault_as_documented(tmp_path, clean):
    p = tmp_path / "s.toml"
    p.write_text(SCEN)
    faults, seed = load_scenario(p, CAL)
    assert [f.kind for f in faults] == ["step", "ramp", "stuck", "dropout", "noise"]
    assert seed == 3
    f2 = inject(clean, faults, CAL, seed=seed, source=str(p))
    assert len(f2.faults) == 5 and f2.truth["injected"]["seed"] == 3
    t, r0, r1 = clean.t, clean.raw, f2.raw
    s = CAL.gyro
    sig, sf = s.noise_sd, s.scale_factors
    w = (t >= 1.0) & (t < 1.5)
    np.testing.assert_allclose(r1[w, 2] - r0[w, 2], 15 * sig[2] / sf[2], rtol=1e-9,
                               err_msg="step size")
    np.testing.assert_array_equal(r1[~w, 2], r0[~w, 2], err_msg="step outside its window")
    ramp = t >= 0.5
    np.testing.assert_allclose(r1[ramp, 1] - r0[ramp, 1],
                               0.05 * sig[1] * (t[ramp] - 0.5) / sf[1], rtol=1e-6, atol=1e-12)
    k = np.flatnonzero(t >= 2.0)
    assert np.all(r1[k, 4] == r0[k[0] - 1, 4]), "stuck holds the last value before onset"
    d = (t >= 0.2) & (t < 0.3)
    assert not f2.valid[d, 5].any() and np.all(np.isnan(r1[d, 5]))
    assert f2.valid[~d, 5].all()
    # noise 3x: the added white noise has variance (9 - 1)·σ² (300 samples: chi-square
    # with 299 dof, 3-sigma band of the variance ratio is ±3·sqrt(2/299) ≈ ±0.25)
    extra = (r1[:, 0] - r0[:, 0]) * sf[0]
    ratio = np.var(extra, ddof=1) / (8 * sig[0] ** 2)
    assert abs(ratio - 1) < 3 * np.sqrt(2 / 299), f"noise variance ratio {ratio}"
    # the untouched sensor is untouched
    np.testing.assert_array_equal(r1[:, 3], r0[:, 3])


def test_spike_hits_the_onset_sample_only(clean):
    from replay.faults import parse_fault
    f = parse_fault("spike:4:50sigma:1.234", CAL)
    raw, _ = apply_faults(clean.t, clean.raw, clean.valid, [f], CAL)
    diff = np.flatnonzero(raw[:, 3] != clean.raw[:, 3])
    assert diff.tolist() == [124]


@pytest.mark.parametrize("text, field", [
    ('schema = "rimu.scenario/2"', "schema"),
    ('schema = "rimu.scenario/1"\n[[faults]]\nkind = "step"\nonset = 1', "faults[1].sensor"),
    ('schema = "rimu.scenario/1"\n[[faults]]\nsensor = 9\nkind = "step"\nsize = "1sigma"\n'
     'onset = 1', "faults[1]"),
    ('schema = "rimu.scenario/1"\n[[faults]]\nsensor = 1\nkind = "bogus"\nonset = 1',
     "faults[1]"),
    ('schema = "rimu.scenario/1"\n[[faults]]\nsensor = 1\nkind = "noise"\nsize = "0.5x"\n'
     'onset = 1', "faults[1].size"),
])
def test_bad_scenario_names_the_field(tmp_path, text, field):
    p = tmp_path / "s.toml"
    p.write_text(text)
    with pytest.raises(FileFormatError) as e:
        load_scenario(p, CAL)
    assert e.value.field == field
