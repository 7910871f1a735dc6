"""The commands compensate the effect terms: ``monitor-file`` (with the flight's
accelerometers), ``replay`` (the sensors' own outputs only); they print what is and is not
applied, record it in the report, and ``--no-effects`` gives the old behaviour bit for bit."""

from __future__ import annotations

import dataclasses
import json

import pytest
from _effects_flight import effect_calibration, flight_with_effects

from fdi.calfile import EffectTerm, load_calibration
from replay.flight import save_flight_dir
from replay.logio import write_flight_log
from rimu.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("eff")
    cal = effect_calibration()
    step = EffectTerm("bias_step", "gyro", 4, 3.0, 0.2, "deg/h", ("time",), {"time_s": 50.0})
    cal = dataclasses.replace(cal, effects=(*cal.effects, step))
    cal.save(d / "cal.json")
    dataclasses.replace(cal, effects=()).save(d / "plain.json")
    fl = flight_with_effects(load_calibration(d / "cal.json"), seed=2, duration_s=30.0)
    save_flight_dir(fl, d / "flight")
    write_flight_log(fl, d / "flight.log")
    return d


def _run(capsys, *argv):
    assert main([str(a) for a in argv]) == 0
    return capsys.readouterr().out


def _detections(report):
    return sum(e["type"] == "detected" for e in report["events"])


def test_monitor_file_compensates_and_says_what_it_cannot(files, capsys):
    d = files
    out = _run(capsys, "monitor-file", d / "flight", "--cal", d / "cal.json",
               "--report", d / "on.json")
    first = out.splitlines()[0]
    assert first == ("compensating: scale_asymmetry on x1 (from rate sign), g_sensitivity on "
                     "y1 (from specific force), g_sensitivity on x2 (from specific force); "
                     "not applied: bias_step on y2 (session-specific (a jump at a time of the "
                     "calibration session), not a sensor property)"), first
    rep = json.loads((d / "on.json").read_text())
    eff = rep["effects"]
    assert eff["schema"] == "rimu.effects-runtime/1" and eff["enabled"]
    assert [(a["name"], a["sensor"]) for a in eff["applied"]] == [
        ("scale_asymmetry", 1), ("g_sensitivity", 2), ("g_sensitivity", 4)]
    assert eff["not_applied"][0]["name"] == "bias_step"
    assert all(m["samples"] == 0 for m in eff["samples_without_input"])
    assert _detections(rep) == 0


def test_monitor_file_no_effects_is_the_old_behaviour(files, capsys):
    d = files
    out_off = _run(capsys, "monitor-file", d / "flight", "--cal", d / "cal.json",
                   "--no-effects", "--report", d / "off.json")
    out_plain = _run(capsys, "monitor-file", d / "flight", "--cal", d / "plain.json",
                     "--report", d / "plain_rep.json")
    off = json.loads((d / "off.json").read_text())
    plain = json.loads((d / "plain_rep.json").read_text())
    assert off.pop("effects")["applied"] == []
    assert off == plain
    assert out_off.splitlines()[0] == (
        "compensating: nothing (--no-effects: 4 effect term(s) switched off: scale_asymmetry "
        "on x1, g_sensitivity on y1, g_sensitivity on x2, bias_step on y2)")
    assert out_off.splitlines()[1:-1] == out_plain.splitlines()[:-1]     # last: "wrote ..."
    assert _detections(off) > 0, "the premise: uncompensated, the effects raise alarms"


def test_monitor_file_without_accelerometers(files, capsys, tmp_path):
    from replay.flight import load_flight_dir

    fl = dataclasses.replace(load_flight_dir(files / "flight"), aux=None)
    save_flight_dir(fl, tmp_path / "noacc")
    out = _run(capsys, "monitor-file", tmp_path / "noacc", "--cal", files / "cal.json")
    assert "g_sensitivity on y1 (needs specific force: no accelerometers in the stream)" \
        in out.splitlines()[0]


def test_replay_compensates_the_rate_terms(files, capsys):
    d = files
    out = _run(capsys, "replay", d / "flight.log", "--cal", d / "cal.json", "--no-progress",
               "--report", d / "r_on.json")
    assert out.splitlines()[0].startswith(
        "compensating: scale_asymmetry on x1 (from rate sign); not applied: g_sensitivity on "
        "y1 (needs specific force: no accelerometers in the stream)")
    on = json.loads((d / "r_on.json").read_text())
    assert [a["name"] for a in on["effects"]["applied"]] == ["scale_asymmetry"]
    _run(capsys, "replay", d / "flight.log", "--cal", d / "cal.json", "--no-progress",
         "--no-effects", "--report", d / "r_off.json")
    _run(capsys, "replay", d / "flight.log", "--cal", d / "plain.json", "--no-progress",
         "--report", d / "r_plain.json")
    off = json.loads((d / "r_off.json").read_text())
    plain = json.loads((d / "r_plain.json").read_text())
    off.pop("effects")
    for r in (off, plain):
        r.pop("timing_s", None)
    assert off == plain
