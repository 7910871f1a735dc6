"""The rimu command: parity output and one-line errors."""

import json
import subprocess
import sys

import numpy as np

from rimu.cli import main


def test_parity_json(capsys):
    assert main(["parity", "tetrad", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(out["V"][0], [-0.40825, -0.40825, -0.40825, 0.70711], atol=5e-6)
    assert out["can_isolate"] is False
    assert all(not p["isolable"] for p in out["isolable_pairs"])


def test_parity_cone6_isolable(capsys):
    assert main(["parity", "cone6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["can_isolate"] is True and len(out["V"]) == 3


def test_error_is_one_line_without_traceback(tmp_path):
    r = subprocess.run([sys.executable, "-m", "rimu", "parity", str(tmp_path / "none.toml")],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "none.toml" in r.stderr
