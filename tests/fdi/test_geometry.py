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
        f"[[sensors]]\nname = 's{i}'\naxis = {[float(v) for v in r]!r}\ngroup = {i // 3}\n"
        for i, r in enumerate(rows))
    cfg = load_configuration(_write(tmp_path, text))
    assert cfg.name == "five" and cfg.n == 5
    assert cfg.groups == ((0, 1, 2), (3, 4))
    np.testing.assert_allclose(cfg.H, rows)


def test_toml_errors_name_the_field(tmp_path):
    with pytest.raises(FileFormatError, match=r"sensors\[2\]\.axis"):
        load_configuration(_write(tmp_path, "[[sensors]]\naxis=[1,0,0]\n[[sensors]]\naxis=[1,0]\n"
                                  "[[sensors]]\naxis=[0,0,1]\n[[sensors]]\naxis=[0,1,0]\n"))
    with pytest.raises(FileFormatError, match="norm"):
        load_configuration(_write(tmp_path, "[[sensors]]\naxis=[1,0,0]\n[[sensors]]\naxis=[2,0,0]\n"
                                  "[[sensors]]\naxis=[0,0,1]\n[[sensors]]\naxis=[0,1,0]\n"))
    with pytest.raises(FileFormatError, match="TOML"):
        load_configuration(_write(tmp_path, "[[sensor]\n"))
    with pytest.raises(ConfigError, match="n >= 4"):
        load_configuration(_write(tmp_path, "[[sensors]]\naxis=[1,0,0]\n"))


def test_collinear_sensors_warn(tmp_path):
    text = ("[[sensors]]\naxis=[1,0,0]\n[[sensors]]\naxis=[-1,0,0]\n"
            "[[sensors]]\naxis=[0,0,1]\n[[sensors]]\naxis=[0,1,0]\n")
    with pytest.warns(CollinearSensorsWarning, match="sensors 1 and 2"):
        load_configuration(_write(tmp_path, text))


def test_old_sensor_table_name_still_loads_with_a_deprecation_warning(tmp_path):
    """Issue 10: configuration files named their tables [[sensor]], every other format
    [[sensors]]; the old spelling keeps working, with a warning."""
    text = ("[[sensor]]\naxis=[1,0,0]\n[[sensor]]\naxis=[0,1,0]\n"
            "[[sensor]]\naxis=[0,0,1]\n[[sensor]]\naxis=[0.6,0.8,0]\n")
    with pytest.warns(DeprecationWarning, match=r"\[\[sensor\]\] is deprecated"):
        cfg = load_configuration(_write(tmp_path, text))
    assert cfg.n == 4
    with pytest.raises(FileFormatError, match=r"\[\[sensors\]\] tables only"):
        load_configuration(_write(tmp_path, text + "[[sensors]]\naxis=[0,0,1]\n"))


def test_unknown_configuration_key_is_refused_with_a_suggestion(tmp_path):
    text = ("[[sensors]]\naxis=[1,0,0]\n[[sensors]]\naxis=[0,1,0]\n"
            "[[sensors]]\naxis=[0,0,1]\n[[sensors]]\naxis=[0.6,0.8,0]\ngruop = 2\n")
    with pytest.raises(FileFormatError) as e:
        load_configuration(_write(tmp_path, text))
    assert e.value.field == "sensors[4].gruop" and e.value.line == 9, str(e.value)
    assert "did you mean 'group'?" in str(e.value)


def test_rank_deficient_file_is_named_by_its_path(tmp_path):
    """Issue 10 (cosmetic): the error named the configuration's internal name only."""
    text = "".join(f"[[sensors]]\naxis={a}\n" for a in
                   ("[1,0,0]", "[0,1,0]", "[0.6,0.8,0]", "[0.8,0.6,0]"))
    with pytest.raises(FileFormatError, match=r"cfg\.toml: .*rank < 3"):
        load_configuration(_write(tmp_path, text))
