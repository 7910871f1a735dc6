"""Each effect found names the effects outside the library it could be absorbing (issue 18:
"say which library terms could alias an effect the library lacks"): in the JSON and the
text of ``rimu diagnose``."""

from _diagnose_sessions import add_signal, calibrate_fast, clean_fast

from calibration.diagnose import diagnose
from calibration.diagnose.library import OUTSIDE_ALIASES, candidates
from fdi.units import DPH
from rimu.commands.diagnose import text


def test_every_builtin_candidate_names_what_it_could_absorb():
    names = {c.name for c in candidates()}
    assert names <= set(OUTSIDE_ALIASES), names - set(OUTSIDE_ALIASES)
    assert all(OUTSIDE_ALIASES[n].strip() for n in names)


def test_effect_found_carries_its_aliases_in_json_and_text():
    s, truth = clean_fast("tetrad-paper", 2)
    t = s.t - s.t[0]
    s = add_signal(s, truth, 1, 10.0 * DPH * t / t[-1])          # a linear drift on gyro 2
    d = diagnose(s, calibrate_fast(s), detectability=False)
    (e,) = d.effects
    assert (e["name"], e["sensors"]) == ("bias_drift", [2])
    assert e["could_absorb"] == OUTSIDE_ALIASES["bias_drift"]
    assert d.to_json()["effects"][0]["could_absorb"] == e["could_absorb"]
    assert f"could instead be absorbing (outside the library): {e['could_absorb']}" in text(d)
