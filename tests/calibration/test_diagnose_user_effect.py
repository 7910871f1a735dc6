"""The user-effect API of docs/diagnose.md: a registered candidate is tested like the
built-in ones; the same candidate loads through the ``rimu.effects`` entry-point group."""

import pytest
from _diagnose_sessions import add_signal, calibrate_fast, session

import calibration.diagnose.library as library
import fdi.effect_specs.registry as effect_registry
from calibration.diagnose import Candidate, diagnose, register_effect
from fdi.units import DPH, G0


def g_squared(data, sensor, params):
    f = data.force @ data.H[sensor]          # specific force along the axis, m/s^2
    return DPH * (f / G0) ** 2               # deg/h of output per unit of the value


G_SQUARED = Candidate(
    name="g_squared_sensitivity", kinds=("gyro",), unit="deg/h per g^2",
    meaning="gyro bias proportional to the squared specific force along the axis",
    regressor=g_squared, inputs=("specific_force",))


@pytest.fixture
def registry(monkeypatch):
    monkeypatch.setattr(library, "_REGISTRY", dict(library._REGISTRY))
    monkeypatch.setattr(library, "_LOADED_ENTRY_POINTS", False)
    return library


def _session_with_g2(k=60.0):
    s, truth = session("tetrad-paper", 15)
    fb = s.inputs()[2]
    f = fb @ truth.gyro.H[1]
    return add_signal(s, truth, 1, k * DPH * (f / G0) ** 2), k


def test_registered_effect_is_found(registry):
    register_effect(G_SQUARED)
    s, k = _session_with_g2()
    d = diagnose(s, calibrate_fast(s))
    names = {(e["name"], e["sensors"][0]) for e in d.effects}
    assert names == {("g_squared_sensitivity", 2)}, d.effects
    (e,) = d.effects
    assert e["unit"] == "deg/h per g^2" and abs(e["estimate"] - k) < 3 * e["estimate_sd"]


def test_without_it_the_structure_is_unexplained(registry):
    s, _ = _session_with_g2()
    d = diagnose(s, calibrate_fast(s))
    assert d.effects == [], d.effects
    assert {(u["kind"], u["sensor"]) for u in d.unexplained_detail} == {("gyro", 2)}


def test_entry_point_group(registry, monkeypatch):
    class EP:
        name, value = "g_squared", "mypackage.effects:G_SQUARED"

        def load(self):
            return G_SQUARED

    monkeypatch.setattr(effect_registry.metadata, "entry_points",
                        lambda group: [EP()] if group == "rimu.effects" else [])
    assert "g_squared_sensitivity" in [c.name for c in library.candidates("gyro")]
