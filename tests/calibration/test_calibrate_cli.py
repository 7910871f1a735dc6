"""``rimu calibrate``: the file, the summary, --compare, and one-line errors on bad input."""

import json
import re

import numpy as np
import pytest
import scipy.stats
from _cli import run as _run
from _sessions import session, with_changes

from calibration.session_io import load_session, save_session
from calibration.truth import save_truth


@pytest.fixture(scope="module")
def tetrad_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("tetrad")
    s, truth = session("tetrad-paper", seed=5)
    save_session(s, d)
    save_truth(truth, {}, {}, d / "truth.json")
    return d


def test_writes_file_summary_and_comparison(tetrad_dir, tmp_path, capsys):
    out = tmp_path / "cal.json"
    code, text, err = _run(capsys, "calibrate", "turntable", tetrad_dir, "--out", out, "--compare",
                           tetrad_dir / "truth.json")
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert doc["schema"] == "rimu.calibration/3" and len(doc["sensors"]["gyro"]) == 4
    for key in ("SF ", "bias ", "misalignment (", "residual rms", "M (sensors 1,2,3)",
                "M (sensors 4)", "v   =", "v_c =", "Earth rate from the outer-axis",
                "turns", "chi2/dof"):
        assert key in text, f"summary shows {key!r}"
    # comparison table: every row's error/sd printed and counted; how many lie beyond 3σ
    # is a statistical statement: at most the binomial 99.9 % quantile for honest σ
    # (the honesty itself is tested over seeds in test_calibrate.py and test_calibrate_mc.py)
    z, n, n_out = comparison_table(text)
    assert n == 17 and z.size == 17
    assert n_out == int(np.sum(np.abs(z) > 3))
    assert n_out <= scipy.stats.binom.ppf(0.999, n, 0.0027)


def comparison_table(text):
    """(error/sd of every row, rows compared, rows beyond 3σ) of a printed comparison."""
    lines = text.splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.split()[-1:] == ["error/sd"])
    m = None
    z = []
    for ln in lines[head + 1:]:
        m = re.match(r"(\d+) parameters compared, (\d+) beyond 3 sigma", ln)
        if m:
            break
        z.append(float(ln.split()[-1]))
    assert m, "the comparison ends with its count line"
    return np.array(z), int(m.group(1)), int(m.group(2))


def test_bias_method_turns_and_no_denoise(tetrad_dir, tmp_path, capsys):
    out = tmp_path / "cal.json"
    code, _, err = _run(capsys, "calibrate", "turntable", tetrad_dir, "--out", out, "--bias-method",
                        "turns", "--no-denoise")
    assert code == 0, err
    doc = json.loads(out.read_text())
    ex = doc["extra"]
    assert ex["method"]["bias"] == "turns" and ex["method"]["denoise"] == "none"
    assert ex["earth_rate_fit"]["denoised"] is False
    np.testing.assert_allclose([e["bias"] for e in doc["sensors"]["gyro"]],
                               ex["gyro_bias"]["turns"], rtol=1e-12)


def test_noise_model_option_and_summary(tmp_path, capsys):
    """A session with 1 deg/h bias instability: 'auto' (default) prints the fitted
    Gauss-Markov bias and the sd factors; '--noise-model white' keeps the white sds."""
    from calibration.presets import preset
    from calibration.simulate import SessionNoise, simulate_session
    from fdi.units import DPH

    seq, truth, _ = preset("tetrad-paper")
    s = simulate_session(None, seq, truth, seed=1,
                         noise=SessionNoise(bias_instability={"gyro": 1.0 * DPH}))
    d = tmp_path / "coloured"
    save_session(s, d)
    docs = {}
    for mode in ("auto", "white"):
        out = tmp_path / f"{mode}.json"
        code, text, err = _run(capsys, "calibrate", "turntable",
                                       d, "--out", out, "--noise-model", mode)
        assert code == 0, err
        assert f"noise model: {mode}:" in text
        docs[mode] = json.loads(out.read_text())
    txt = _run(capsys, "calibrate", "turntable", d, "--out", tmp_path / "x.json")[1]
    assert "gyro: Gauss-Markov bias" in txt and "sigma at correlation" in txt, txt
    assert docs["auto"]["extra"]["noise_model"]["gyro"]["applied"] is True
    sd_a = np.array([e["bias_sd"] for e in docs["auto"]["sensors"]["gyro"]])
    sd_w = np.array([e["bias_sd"] for e in docs["white"]["sensors"]["gyro"]])
    np.testing.assert_allclose(
        sd_a / sd_w, docs["auto"]["extra"]["noise_model"]["gyro"]["sd_factor"]["bias"],
        rtol=1e-6, err_msg="bias sd factor in the file")
    assert np.all(sd_a > sd_w)


def _one_line_error(capsys, *argv):
    code, _, err = _run(capsys, *argv)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rimu: error: "), err
    assert "Traceback" not in err
    return lines[0]


def _copy(src, dst):
    dst.mkdir()
    for name in ("manifest.json", "samples.csv"):
        (dst / name).write_bytes((src / name).read_bytes())
    return dst


def test_missing_column(tetrad_dir, tmp_path, capsys):
    d = _copy(tetrad_dir, tmp_path / "s")
    lines = (d / "samples.csv").read_text().splitlines()
    head = lines[0].split(",")
    j = head.index("gyro.g3")
    (d / "samples.csv").write_text("\n".join(",".join(c for k, c in enumerate(r.split(","))
                                                      if k != j) for r in lines) + "\n")
    msg = _one_line_error(capsys, "calibrate", "turntable", d, "--out", tmp_path / "c.json")
    assert str(d) in msg and "gyro.g3" in msg


def test_nan_sample(tetrad_dir, tmp_path, capsys):
    d = _copy(tetrad_dir, tmp_path / "s")
    lines = (d / "samples.csv").read_text().splitlines()
    row = 1 + 36000 + 5                             # a sample of step 11 (3600 per step)
    cells = lines[row].split(",")
    cells[-1] = "nan"
    lines[row] = ",".join(cells)
    (d / "samples.csv").write_text("\n".join(lines) + "\n")
    msg = _one_line_error(capsys, "calibrate", "turntable", d, "--out", tmp_path / "c.json")
    assert "samples.csv" in msg and "step 11" in msg


def test_unknown_unit(tetrad_dir, tmp_path, capsys):
    d = _copy(tetrad_dir, tmp_path / "s")
    m = json.loads((d / "manifest.json").read_text())
    m["raw_units"]["gyro"] = "furlongs"
    (d / "manifest.json").write_text(json.dumps(m))
    msg = _one_line_error(capsys, "calibrate", "turntable", d, "--out", tmp_path / "c.json")
    assert "manifest.json" in msg and "furlongs" in msg


def _rewrite(tetrad_dir, d, keep_fn, steps=None):
    s = load_session(tetrad_dir)
    keep = keep_fn(s)
    s2 = with_changes(s, t=s.t[keep], step=s.step[keep], inner=s.inner[keep],
                      outer=s.outer[keep], inner_rate=s.inner_rate[keep],
                      outer_rate=s.outer_rate[keep], raw_gyro=s.raw_gyro[keep],
                      steps=s.steps if steps is None else steps(s))
    save_session(s2, d)
    return d


def test_not_enough_excitation(tetrad_dir, tmp_path, capsys):
    d = _rewrite(tetrad_dir, tmp_path / "s", lambda s: s.step <= 6, lambda s: s.steps[:6])
    msg = _one_line_error(capsys, "calibrate", "turntable", d, "--out", tmp_path / "c.json")
    assert str(d) in msg and "1/2, 3/4, 5/6" in msg and "rank of R is 2" in msg


def test_step_with_too_few_samples(tetrad_dir, tmp_path, capsys):
    def keep(s):
        k = np.ones(s.t.shape, bool)
        k[np.flatnonzero(s.step == 12)[4:]] = False
        return k
    d = _rewrite(tetrad_dir, tmp_path / "s", keep)
    msg = _one_line_error(capsys, "calibrate", "turntable", d, "--out", tmp_path / "c.json")
    # the loader or the estimator (whichever sees it first) names the step and the minimum
    assert str(d) in msg and "step 12" in msg and "4 sample" in msg and "at least 10" in msg


def test_plots(tetrad_dir, tmp_path, capsys):
    code, text, err = _run(capsys, "calibrate", "turntable",
                                   tetrad_dir, "--out", tmp_path / "c.json",
                           "--plot", tmp_path / "plots")
    assert code == 0, err
    for name in ("residual_steps_gyro.png", "allan_gyro.png", "earth_rate_fit.png"):
        p = tmp_path / "plots" / name
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert f"wrote {p}" in text
