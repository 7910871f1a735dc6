"""Configurations: built-ins, TOML files, validation."""

import numpy as np
import pytest

from fdi.errors import ConfigError, FileFormatError
from fdi.geometry import CollinearSensorsWarning, cone6, load_configuration, tetrad


def test_builtins_are_unit_rank3():
    for cfg in (tetrad(), cone6()):
        np.testing.assert_allclose(np.linalg.norm(cfg.H, axis=1), 1.0, err_msg=cfg.name)
        assert np.linalg.matrix_rank(cfg.H) == 3


def test_cone6_subimus_are_orthogonal_triads():
    H = cone6().H
    for g in cone6().groups:
        np.testing.assert_allclose(H[list(g)] @ H[list(g)].T, np.eye(3), atol=1e-12)


def _write(tmp_path, text):
    p = tmp_path / "cfg.toml"
    p.write_text(text)
    return p


def test_toml_configuration(tmp_path):
    rows = cone6().H[:5]
    text = "name = 'five'\n" + "".join(
        f"[[sensor]]\nname = 's{i}'\naxis = {[float(v) for v in r]!r}\ngroup = {i // 3}\n"
        for i, r in enumerate(rows))
    cfg = load_configuration(_write(tmp_path, text))
    assert cfg.name == "five" and cfg.n == 5
    assert cfg.groups == ((0, 1, 2), (3, 4))
    np.testing.assert_allclose(cfg.H, rows)


def test_toml_errors_name_the_field(tmp_path):
    with pytest.raises(FileFormatError, match=r"sensor\[2\]\.axis"):
        load_configuration(_write(tmp_path, "[[sensor]]\naxis=[1,0,0]\n[[sensor]]\naxis=[1,0]\n"
                                  "[[sensor]]\naxis=[0,0,1]\n[[sensor]]\naxis=[0,1,0]\n"))
    with pytest.raises(FileFormatError, match="norm"):
        load_configuration(_write(tmp_path, "[[sensor]]\naxis=[1,0,0]\n[[sensor]]\naxis=[2,0,0]\n"
                                  "[[sensor]]\naxis=[0,0,1]\n[[sensor]]\naxis=[0,1,0]\n"))
    with pytest.raises(FileFormatError, match="TOML"):
        load_configuration(_write(tmp_path, "[[sensor]\n"))
    with pytest.raises(ConfigError, match="n >= 4"):
        load_configuration(_write(tmp_path, "[[sensor]]\naxis=[1,0,0]\n"))


def test_collinear_sensors_warn(tmp_path):
    text = ("[[sensor]]\naxis=[1,0,0]\n[[sensor]]\naxis=[-1,0,0]\n"
            "[[sensor]]\naxis=[0,0,1]\n[[sensor]]\naxis=[0,1,0]\n")
    with pytest.warns(CollinearSensorsWarning, match="sensors 1 and 2"):
        load_configuration(_write(tmp_path, text))
