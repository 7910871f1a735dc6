"""One specification per effect (fdi.effect_specs): its forms agree with each other, and a
user's spec gets the same treatment as a built-in one.

- every built-in run-time form gives the session regressor × estimate (noise-free session);
- every built-in simulator knob on the output adds value × session regressor (up to a
  constant: the temperature knob's reference is the start temperature, the regressor's the
  session mean);
- the derived tables (simulator knobs, diagnosis candidates, run-time lists, bounds) hold
  every built-in effect exactly once;
- a user EffectSpec registered through ``register_effect`` is a diagnosis candidate and the
  monitor compensates it with its run-time form (block and one-sample paths, same bits).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import calibration.diagnose.library as library
import fdi.effect_specs.registry as registry
from calibration.diagnose.context import kind_data
from calibration.effects import EFFECTS
from calibration.presets import preset
from calibration.simulate import EffectContext, SessionNoise, simulate_session
from fdi.calfile import EffectTerm
from fdi.effect_specs import BUILTIN, EffectSpec, RuntimeForm, builtin_names
from fdi.effects import COMPENSABLE, NOT_COMPENSABLE, Compensator, term_correction
from fdi.units import DPH, G0


@pytest.fixture(scope="module")
def session():
    """A noise-free tetrad session with the simulated temperature column (knob at 0)."""
    seq, truth, _ = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=4, noise=SessionNoise(white=False),
                         effects={"temperature": 0.0})
    return s, truth, kind_data(s, truth)["gyro"]


def _params(spec: EffectSpec, d, i: int) -> dict:
    return spec.fixed_params(d, i) if spec.fixed_params else {}


@pytest.mark.parametrize("spec", [s for s in BUILTIN if s.runtime], ids=lambda s: s.name)
def test_runtime_form_is_the_session_regressor(session, spec):
    _, _, d = session
    for i in range(d.n):
        p = _params(spec, d, i)
        est = 0.7 * (1 + 0.3 * i)
        term = EffectTerm(spec.name, "gyro", i, est, 0.1, spec.unit_for("gyro"), spec.inputs, p)
        want = est * np.asarray(spec.regressor(d, i, p), float)
        got = term_correction(term, d.H[i], s=d.s[:, i], force=d.force,
                              temperature=d.temperature[:, i])
        assert np.max(np.abs(want)) > 0
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)))


@pytest.mark.parametrize("spec", [s for s in BUILTIN if s.simulator and s.simulator.apply],
                         ids=lambda s: s.name)
def test_simulator_knob_adds_value_times_the_session_regressor(session, spec):
    _, _, d = session
    ctx = EffectContext(t=d.t - d.t[0], duration_s=d.duration_s, table_rate=d.table_rate,
                        f_along=d.force @ d.H.T)
    v = 1e4                     # large: the knob adds to s, compared after subtracting s
    added = spec.simulator.apply(d.s.copy(), v, ctx) - d.s
    for i in range(d.n):
        z = v * np.asarray(spec.regressor(d, i, _params(spec, d, i)), float)
        diff = added[:, i] - z
        scale = np.max(np.abs(z))
        assert scale > 0
        assert np.ptp(diff) < 1e-9 * scale, (spec.name, i, np.ptp(diff) / scale)


def test_the_derived_tables_cover_each_builtin_once():
    names = builtin_names()
    assert len(set(names)) == len(names)
    assert [c.name for c in library.candidates()][:len(names)] == list(names)
    assert set(COMPENSABLE) | set(NOT_COMPENSABLE) == set(names)
    assert not set(COMPENSABLE) & set(NOT_COMPENSABLE)
    assert set(EFFECTS) == {s.name for s in BUILTIN if s.simulator}
    assert set(library.OUTSIDE_ALIASES) == set(names)
    assert sorted(s.runtime.code for s in BUILTIN if s.runtime) == [0, 1, 2, 3]


def _g_squared_spec() -> EffectSpec:
    def reg(d, i, p):
        return DPH * ((d.force @ d.H[i]) / G0) ** 2

    return EffectSpec(
        "g_squared_user", ("gyro",), "gyro bias proportional to the squared specific force",
        "deg/h per g^2", reg, ("specific_force",),
        runtime=RuntimeForm(
            "specific_force", "specific force", 7, ("gyro",),
            lambda est, p, kind: est * DPH / G0**2,
            lambda p, axis, var: (float(axis[0]), float(axis[1]), float(axis[2])),
            lambda k, x, e: k * (x[0] * e[0] + x[1] * e[1] + x[2] * e[2]) ** 2))


@pytest.fixture
def registries(monkeypatch):
    monkeypatch.setattr(registry, "_SPECS", dict(registry._SPECS))
    monkeypatch.setattr(library, "_REGISTRY", dict(library._REGISTRY))


def test_a_user_spec_is_a_candidate_and_compensated(session, registries):
    s, truth, d = session
    spec = _g_squared_spec()
    library.register_effect(spec)
    assert library.get_candidate(spec.name).regressor is spec.regressor
    est = 25.0
    term = EffectTerm(spec.name, "gyro", 2, est, 1.0, spec.unit, spec.inputs, {})
    cal = dataclasses.replace(truth, effects=(term,))
    comp = Compensator(cal, available={"specific_force": range(4)})
    assert [a.term.name for a in comp.applied] == [spec.name] and comp.skipped == ()
    got = comp.block(s.raw_gyro, force=d.force)
    want = np.zeros_like(got)
    want[:, 2] = est * spec.regressor(d, 2, {})
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.max(np.abs(want)))
    rows = np.array([comp.one(s.raw_gyro[k], d.force[k]) for k in range(0, d.N, 997)])
    np.testing.assert_array_equal(rows, got[::997])
    # without the force in the stream the monitor says why, with the spec's input name
    (skip,) = Compensator(cal).skipped
    assert skip.reason.startswith("needs specific force")
