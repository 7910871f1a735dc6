"""``rimu demo`` runs the whole chain and its outputs say what they should."""

import json
import re

import scipy.stats

from fdi.calfile import load_calibration
from rimu.cli import main


def test_demo_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--duration", "60"]) == 0
    text = capsys.readouterr().out
    # one calibration of a simulated session: the count beyond 3σ is at most the binomial
    # 99.9 % quantile for honest σ (honesty over seeds: tests/calibration/test_calibrate*)
    m = re.search(r"(\d+) parameters compared, (\d+) beyond 3 sigma", text)
    assert m, "the demo prints the comparison with the truth"
    n, n_out = int(m.group(1)), int(m.group(2))
    assert n > 30 and n_out <= scipy.stats.binom.ppf(0.999, n, 0.0027)
    cal = load_calibration(out / "cal.json")
    assert set(cal.sets) == {"gyro", "accel"} and cal.gyro.n == 6
    report = json.loads((out / "report.json").read_text())
    assert report["schema"] == "rimu.report/1"
    s = report["summary"]
    assert s["false_alarms"] == 0
    assert sorted(s["isolated_sensors"]) == [3, 5]
    f = report["frames"]
    assert f["read"] == f["used"] + sum(f["rejected"].values())
    times = [e["t"] for e in report["events"]]
    assert times == sorted(times)
    # every live line names its sensor or says it has none (issue 30: "sensor None")
    assert "sensor None" not in text
    assert all(re.search(r"sensor +(\d+ \(\S+\)|-)", ln)
               for ln in text.splitlines() if re.match(r"\s+t=\s*[\d.]+ s\s+sensor", ln))
    assert (out / "replay.rrd").stat().st_size > 0
    # the picture, drawn without a display (matplotlib Agg), and the parity in the recording
    import matplotlib.image
    import numpy as np
    import rerun.chunk

    img = matplotlib.image.imread(out / "replay.png")
    assert img.shape[0] > 500
    rows = [r for ch in rerun.chunk.RrdReader(out / "replay.rrd").stream()
            if str(ch.entity_path) == "/parity" and not ch.is_static
            for r in ch.to_record_batch().column("Scalars:scalars").to_pylist()]
    par = np.array(rows, float)
    assert par.shape == (report["samples"], 3)
    assert np.isfinite(par).any(axis=1).all()       # was 6000 x 3 NaN on the block path
    assert "replay.png" in text and "--web-viewer" in text
