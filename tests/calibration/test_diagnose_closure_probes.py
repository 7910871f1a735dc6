"""The two probes of issue 18's turntable closure, on synthetic sets (fast).

- Line stationarity (:mod:`calibration.diagnose.stationarity`): a line whose amplitude
  grows over the session is refused (the sensor "unexplained", the line a partial fit, the
  verdict "effects suspected" through :func:`calibration.diagnose.adequacy.decide`); a line
  of constant amplitude passes, its per-segment amplitudes agree with the truth within
  their σ, and over 150 white-noise sets (frequency searched as the product does) the
  fraction of p below 0.05 stays within the 99.9 % binomial quantile.
- Change points named ``bias_step`` (:func:`calibration.diagnose.selection._promote_steps`):
  a step the probes see and the selection did not take is claimed as ``bias_step`` on its
  sensor at its time; a late quadratic drift, which a step does not explain, stays
  "unexplained".

The levels on full presets sessions are a campaign (test_closure_levels.py). Also
``rimu calibrate turntable --sensor-class`` (the class whose physical bounds label effect terms).
"""

import dataclasses

import numpy as np
import scipy.stats
from _cli import run
from test_diagnose_holdout import _synthetic

from calibration.diagnose import format_adequacy, get_candidate
from calibration.diagnose.adequacy import adequacy_record
from calibration.diagnose.library import line_search
from calibration.diagnose.selection import Selection, _family, _probe, select
from calibration.diagnose.stationarity import line_stationarity, segments
from calibration.presets import preset
from fdi.adequacy import SUSPECTED
from fdi.calfile import EffectTerm
from fdi.units import DPH

LINE = get_candidate("periodic_line")
STEP = get_candidate("bias_step")
F_HZ = 0.37                     # 16 s session (1600 samples at 100 Hz): about 6 cycles


def _with_line(rng, amplitude, sensor=1):
    """Synthetic set (white noise of sd 1, SI) with a line on ``sensor`` whose amplitude
    is ``amplitude(t/T)`` in deg/h (the unit of the candidate's columns)."""
    d, models = _synthetic(rng)
    ph = 2 * np.pi * F_HZ * d.t + 0.7
    d.y[:, sensor] += DPH * amplitude(d.t / d.t[-1]) * np.sin(ph)
    for i in range(d.n):
        models[("gyro", i)] = type(models[("gyro", i)])(d.y[:, i], np.column_stack(
            [np.ones(d.N), d.x]))
    return d, models


def _fit_line(d, model, i, search=True):
    par = (line_search(d, i, model.Q, model.e)[0] if search
           else {"frequency_hz": F_HZ})
    model.add(LINE.columns(d, i, par))
    return par


def test_growing_line_is_refused():
    rng = np.random.default_rng(1)
    amp = 0.5 / DPH           # 0.5 rad/s of amplitude units at the start ...
    d, models = _with_line(rng, lambda u: amp * (1 + 6 * u))     # ... 3.5 at the end
    par = _fit_line(d, models[("gyro", 1)], 1)
    rec = line_stationarity(d, 1, models[("gyro", 1)], LINE, par)
    assert rec["test"] == "line_stationarity" and rec["dof"] == 2 * (len(segments(d)) - 1)
    assert rec["p_value"] < 1e-10, rec["p_value"]
    a = [s["amplitude"] for s in rec["segments"]]
    assert all(np.diff(a) > 0), a                 # grows segment by segment
    # through the selection: the line is found, then refused; the verdict is decided
    sel = select({"gyro": d}, [LINE, STEP], alpha=0.01)
    assert ("periodic_line", 1) in [(c.candidate.name, c.sensor) for c in sel.partial]
    assert not sel.claimed
    assert {(u["sensor"], u["test"]) for u in sel.unexplained} >= {(2, "line_stationarity")}
    rec = adequacy_record(sel, 0.01, effects_refit=True)
    assert rec["verdict"] == SUSPECTED
    assert any(w.startswith("gyro 2: unexplained (line_stationarity") for w in rec["where"])


def test_constant_line_passes_and_reads_its_amplitude():
    rng = np.random.default_rng(2)
    amp = 0.8 / DPH
    d, models = _with_line(rng, lambda u: amp + 0 * u)
    par = _fit_line(d, models[("gyro", 1)], 1)
    rec = line_stationarity(d, 1, models[("gyro", 1)], LINE, par)
    assert rec["p_value"] > 1e-3, rec["p_value"]
    for s in rec["segments"]:
        assert abs(s["amplitude"] - amp) < 4 * s["amplitude_sd"], (s, amp)
    sel = select({"gyro": d}, [LINE, STEP], alpha=0.01)
    assert [(c.candidate.name, c.sensor) for c in sel.claimed] == [("periodic_line", 1)]
    assert not sel.unexplained


def test_stationarity_level_on_constant_lines():
    """150 sets, a constant line with the frequency searched and refined (the product's
    path): p < 0.05 in at most the 99.9 % quantile of Binomial(150, 0.05) (the test is
    conservative if anything: the fitted frequency removes the phase drift a frequency
    error leaves; measured 6 of 150 below 0.05, 1 below 0.01, KS against uniform p 5e-4:
    conservative, so uniformity is not asserted)."""
    rng = np.random.default_rng(3)
    ps = []
    for _ in range(150):
        d, models = _with_line(rng, lambda u: 0.4 / DPH + 0 * u)
        par = _fit_line(d, models[("gyro", 1)], 1)
        ps.append(line_stationarity(d, 1, models[("gyro", 1)], LINE, par)["p_value"])
    ps = np.asarray(ps)
    assert np.sum(ps < 0.05) <= scipy.stats.binom.ppf(0.999, ps.size, 0.05), np.mean(ps < 0.05)


def _probed(d, signal, sensor):
    d.y[:, sensor] += signal
    out = Selection()
    _family({"gyro": d}, [STEP], out)
    _probe({"gyro": d}, out, 0.01, step=STEP)
    return out


def test_change_point_is_named_bias_step_on_its_sensor():
    rng = np.random.default_rng(4)
    d, _ = _synthetic(rng)
    t0 = d.t[int(0.55 * d.N)]
    out = _probed(d, 0.3 * (d.t >= t0), 2)      # 0.3 sd: z ~ 6 over the session
    assert not out.unexplained, out.unexplained
    assert [(c.candidate.name, c.sensor) for c in out.claimed] == [("bias_step", 2)]
    assert abs(out.claimed[0].params["time_s"] - t0) < 0.5
    assert out.promoted and out.promoted[0]["sensor"] == 3


def test_quadratic_drift_is_not_named_a_step():
    rng = np.random.default_rng(5)
    d, _ = _synthetic(rng)
    u = np.clip(d.t / d.t[-1] - 0.4, 0, None) / 0.6
    out = _probed(d, 1.5 * u**2, 2)
    assert not out.claimed and not out.promoted
    assert {u["sensor"] for u in out.unexplained} == {3}


# ---- rimu calibrate turntable --sensor-class -------------------------------------

def test_calibrate_sensor_class_sets_the_bounds(capsys, tmp_path):
    """``format_adequacy(cal, sensor_class=...)`` (what ``rimu calibrate turntable --sensor-class``
    prints): 100 °/h per g of g-sensitivity is beyond the FOG bound the tetrad's noise
    implies, within the MEMS one when the class is given; the option is refused for the
    other kinds of session, in one line, exit 2."""
    truth = preset("tetrad-paper").truth
    term = EffectTerm("g_sensitivity", "gyro", 1, 100.0, 3.0, "deg/h per g",
                      ("specific force",), {})
    cal = dataclasses.replace(truth, effects=(term,))

    def note(**kw):
        lines = format_adequacy(cal, **kw)
        i = next(k for k, ln in enumerate(lines) if ln.startswith("effect g_sensitivity"))
        return lines[i + 1]

    assert "absorbing something else" in note()
    assert "absorbing something else" in note(sensor_class="fog")
    assert "absorbing" not in note(sensor_class="mems")
    (tmp_path / "fl").mkdir()       # the output may not lie inside the input (issue 30)
    code, out, err = run(capsys, "calibrate", "in-flight", tmp_path / "fl", "--out",
                         tmp_path / "c.json", "--sensor-class", "mems")
    assert code == 2 and not out and len(err.strip().splitlines()) == 1, err
    assert "--sensor-class" in err
