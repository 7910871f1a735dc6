"""rimu.calibration/2: effects and adequacy round trip, /1 files still load, loader errors
name the field."""

import dataclasses
import json

import pytest
from _diagnose_sessions import calibrate_fast, session

from calibration.diagnose import diagnose
from fdi.calfile import EffectTerm, load_calibration
from fdi.errors import FileFormatError


@pytest.fixture(scope="module")
def fitted():
    s, _ = session("tetrad-paper", 9, effects={"bias_drift": 10.0}, effect_sensors=[2])
    return s, diagnose(s, calibrate_fast(s)).calibration


def test_effects_and_adequacy_round_trip(tmp_path, fitted):
    s, cal = fitted
    p = tmp_path / "cal.json"
    cal.save(p)
    doc = json.loads(p.read_text())
    assert doc["schema"] == "rimu.calibration/3"
    assert doc["effects"][0]["name"] == "bias_drift" and doc["effects"][0]["sensor"] == 2
    back = load_calibration(p)
    assert len(back.effects) == 1 and isinstance(back.effects[0], EffectTerm)
    e0, e1 = cal.effects[0], back.effects[0]
    assert (e1.name, e1.kind, e1.sensor, e1.unit) == (e0.name, e0.kind, e0.sensor, e0.unit)
    assert e1.estimate == pytest.approx(e0.estimate, rel=1e-12)
    # the drift found and fitted, nothing else suspected; the tests ran against white +
    # Gauss-Markov noise (the drift made the white-noise residual read as coloured), which
    # cannot rule out every slow effect at 5 sigma: "effects not ruled out", with the limits
    assert back.adequacy["verdict"] == cal.adequacy["verdict"]
    assert back.adequacy["verdict"] in ("adequate", "adequate within sequence limits",
                                        "effects not ruled out")
    assert back.adequacy["not_ruled_out"] == json.loads(json.dumps(
        cal.adequacy["not_ruled_out"]))
    assert (back.adequacy["verdict"] == "effects not ruled out") == bool(
        back.adequacy["not_ruled_out"])
    # a calibration with its effect: diagnosing it again finds nothing more
    again = diagnose(s, back)
    assert again.effects == [] and not again.unexplained


def test_version_1_file_loads_without_effects(tmp_path, fitted):
    _, cal = fitted
    doc = dataclasses.replace(cal, effects=(), adequacy=None).to_dict()
    doc["schema"] = "rimu.calibration/1"
    del doc["effects"]
    doc.pop("residual_tails", None)                 # /3 only
    p = tmp_path / "old.json"
    p.write_text(json.dumps(doc))
    back = load_calibration(p)
    assert back.effects == () and back.adequacy is None
    back.save(tmp_path / "new.json")                       # migrated on save
    assert json.loads((tmp_path / "new.json").read_text())["schema"] == "rimu.calibration/3"


@pytest.mark.parametrize(("edit", "field"), [
    (lambda d: d["effects"][0].update(sensor=9), "effects[1].sensor"),
    (lambda d: d["effects"][0].update(kind="magnetometer"), "effects[1].kind"),
    (lambda d: d["effects"][0].pop("estimate_sd"), "effects[1].estimate_sd"),
    (lambda d: d["effects"][0].update(estimate_sd=-1), "effects[1].estimate_sd"),
    (lambda d: d["effects"][0].update(colour="red"), "effects[1].colour"),
    (lambda d: d["adequacy"].update(verdict="fine"), "adequacy.verdict"),
])
def test_loader_errors_name_the_field(tmp_path, fitted, edit, field):
    _, cal = fitted
    doc = cal.to_dict()
    edit(doc)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError) as e:
        load_calibration(p)
    msg = str(e.value)
    assert "bad.json" in msg and field in msg and "\n" not in msg, msg
