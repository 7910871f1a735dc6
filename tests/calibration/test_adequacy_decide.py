"""The one adequacy verdict (issue 21, item 2): the strings in ``fdi.adequacy``, the
decision in ``calibration.diagnose.adequacy.decide``, the file format unchanged.

``calibrate_checked`` and ``diagnose`` build the record in stages; the verdict read off any
record is the worst one whose evidence it holds, whatever the stage that added it.
"""

import itertools
import json
from types import SimpleNamespace

import pytest

from calibration.diagnose.adequacy import (
    ADVICE,
    SEQUENCE_ADVICE,
    adequacy_record,
    decide,
    with_holdout,
    with_limits,
)
from calibration.presets import preset
from fdi.adequacy import ADEQUATE, NOT_RULED_OUT, SUSPECTED, VERDICTS, WITHIN_SEQUENCE_LIMITS
from fdi.calfile import calibration_from_dict
from fdi.errors import FileFormatError

_LIMIT = {"name": "warmup", "kind": "gyro", "sensor": 1, "size": 2.0, "unit": "deg/h",
          "parameter": "bias", "shift_sigma": 5.0, "power": 0.4}
_FOLD = {"kind": "gyro", "sensor": 2, "sensor_name": "g2", "fold": 1, "steps": [1, 4],
         "chi2": 30.0, "dof": 4, "p_value": 1e-6}


def test_the_verdict_strings_are_the_file_formats_best_first():
    assert VERDICTS == ("adequate", "adequate within sequence limits",
                        "effects not ruled out", "effects suspected")
    assert (ADEQUATE, WITHIN_SEQUENCE_LIMITS, NOT_RULED_OUT, SUSPECTED) == VERDICTS


@pytest.mark.parametrize("where, failed, session, sequence",
                         list(itertools.product([False, True], repeat=4)))
def test_the_worst_evidence_decides(where, failed, session, sequence):
    rec = {"where": ["gyro 1: warmup"] if where else [],
           "holdout": {"passed": not failed},
           "not_ruled_out": [_LIMIT] if session else [],
           "sequence_limits": [_LIMIT] if sequence else []}
    present = [v for v, on in ((SUSPECTED, where or failed), (NOT_RULED_OUT, session),
                               (WITHIN_SEQUENCE_LIMITS, sequence)) if on]
    assert decide(rec) == max(present, key=VERDICTS.index, default=ADEQUATE)


def test_missing_stages_count_as_no_evidence():
    assert decide({}) == ADEQUATE
    assert decide({"where": []}) == ADEQUATE


def _selection(claimed=(), unexplained=()):
    return SimpleNamespace(
        claimed=[SimpleNamespace(kind="gyro", sensor=i, candidate=SimpleNamespace(name=n))
                 for i, n in claimed],
        unexplained=[{"kind": "gyro", "sensor": s, "test": "slow trend"} for s in unexplained],
        noise_null={"gyro": "white"})


def test_effects_a_refit_holds_are_found_not_suspected():
    sel = _selection(claimed=[(2, "warmup")])
    calib = adequacy_record(sel, 0.01)                  # rimu calibrate: the model lacks it
    assert calib["verdict"] == SUSPECTED and calib["where"] == ["gyro 3: warmup"]
    refit = adequacy_record(sel, 0.01, effects_refit=True)   # rimu diagnose: refit holds it
    assert refit["verdict"] == ADEQUATE and refit["where"] == []
    assert refit["effects_found"] == ["gyro 3: warmup"] and refit["monitor"]
    both = adequacy_record(_selection([(2, "warmup")], [1]), 0.01, effects_refit=True)
    assert both["verdict"] == SUSPECTED
    assert both["where"] == ["gyro 3: warmup", "gyro 1: unexplained (slow trend)"]
    assert "effects_found" not in both


def test_stages_add_evidence_and_advice():
    rec = adequacy_record(_selection(), 0.01)
    assert rec["verdict"] == ADEQUATE and "advice" not in rec
    ho = {"schema": "rimu.holdout/1", "passed": True, "alpha": 0.01, "threshold": 1e-3,
          "folds": [_FOLD], "failed": [], "not_tested": [], "worst": _FOLD}
    rec = with_holdout(rec, ho)
    assert rec["verdict"] == ADEQUATE
    seq = with_limits(rec, [{**_LIMIT, "limit": "sequence"}], 0.99)
    assert seq["verdict"] == WITHIN_SEQUENCE_LIMITS and seq["advice"] == SEQUENCE_ADVICE
    nro = with_limits(rec, [{**_LIMIT, "limit": "sequence"}, {**_LIMIT, "limit": "session"}],
                      0.99)
    assert nro["verdict"] == NOT_RULED_OUT and nro["advice"] == ADVICE
    bad = with_holdout(rec, {**ho, "passed": False, "failed": [_FOLD]})
    assert bad["verdict"] == SUSPECTED and bad["where"][0].startswith("gyro 2: held-out")
    # limits never lift a suspected verdict
    assert with_limits(bad, [{**_LIMIT, "limit": "session"}], 0.99)["verdict"] == SUSPECTED


@pytest.mark.parametrize("verdict", VERDICTS)
def test_every_verdict_loads_from_a_file(verdict):
    doc = json.loads(json.dumps(preset("tetrad-paper")[1].to_dict()))
    doc["adequacy"] = {"verdict": verdict, "alpha": 0.01, "where": []}
    assert calibration_from_dict(doc).adequacy["verdict"] == verdict
    doc["adequacy"]["verdict"] = verdict.upper()
    with pytest.raises(FileFormatError, match=r"adequacy.*verdict"):
        calibration_from_dict(doc)
