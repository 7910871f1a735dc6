"""The loader toolkit (fdi.fileio.Fields): typed getters, one-line errors, unknown keys."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fdi.errors import FileFormatError
from fdi.fileio import Fields, check_schema, toml_key_line


def _err(fn) -> FileFormatError:
    with pytest.raises(FileFormatError) as ei:
        fn()
    e = ei.value
    assert "\n" not in str(e), str(e)
    return e


def test_number_constraints_name_the_field():
    r = Fields({"a": 1, "b": -2.0, "c": True, "d": float("nan"), "e": 5,
                "f": None}, "x.json", "top")
    assert r.number("a", positive=True) == 1.0 and isinstance(r.number("a"), float)
    assert r.number("missing", 7.5) == 7.5
    assert r.number("f", 3.0) == 3.0                     # JSON null takes the default
    for key, kw, what in (("b", {"positive": True}, "positive"),
                          ("b", {"nonnegative": True}, ">= 0"),
                          ("c", {}, "expected a number, got True"),
                          ("d", {}, "finite"),
                          ("e", {"lo": 0, "hi": 4}, "in [0, 4]")):
        e = _err(lambda key=key, kw=kw: r.number(key, **kw))
        assert e.field == f"top.{key}" and what in str(e) and e.path == "x.json", str(e)
    e = _err(lambda: r.number("nope"))
    assert e.field == "top.nope" and "missing" in str(e)


def test_integer_string_choice_boolean():
    r = Fields({"i": 3, "f": 3.0, "s": "", "c": "gyr", "b": "yes"}, "y.toml")
    assert r.integer("i", lo=1, hi=3) == 3
    assert "expected an integer, got 3.0" in str(_err(lambda: r.integer("f")))
    assert "1..2" in str(_err(lambda: r.integer("i", lo=1, hi=2)))
    assert r.string("s", nonempty=False) == ""
    assert "non-empty string" in str(_err(lambda: r.string("s")))
    assert "did you mean 'gyro'?" in str(_err(lambda: r.choice("c", ("gyro", "accel"))))
    assert "true or false" in str(_err(lambda: r.boolean("b")))
    assert r.choice("absent", ("a", "b"), "b") == "b" and r.boolean("absent2", False) is False


def test_array_shapes_and_lists():
    r = Fields({"m": [[1, 2, 3], [4, 5, 6]], "v": [1, "x"], "n": [1, None, 2], "l": []},
               "z.json")
    np.testing.assert_array_equal(r.array("m", (None, 3)), [[1, 2, 3], [4, 5, 6]])
    assert "expected shape 3×3, got 2×3" in str(_err(lambda: r.array("m", (3, 3))))
    assert "array of numbers" in str(_err(lambda: r.array("v", (2,))))
    e = _err(lambda: r.numbers("n"))
    assert e.field == "n[2]", str(e)
    assert "non-empty list" in str(_err(lambda: r.numbers("l")))
    assert r.array("absent", (3,), None) is None


def test_mapping_tables_and_free():
    doc = {"sub": {"k": 1}, "rows": [{"a": 1}, 5], "meta": {"anything": [1, 2]}}
    r = Fields(doc, "w.json")
    sub = r.mapping("sub")
    assert sub.integer("k") == 1 and sub.name("k") == "sub.k"
    rows = _err(lambda: r.tables("rows"))
    assert rows.field == "rows[2]" and "expected an object" in str(rows)
    assert r.free("meta") == {"anything": [1, 2]}
    assert isinstance(r.mapping("absent", {}), Fields)
    assert r.tables("none", [], nonempty=False) == []


def test_unknown_keys_are_refused_with_a_suggestion():
    r = Fields({"axis_nomnal": [0, 0, 1], "message": "M"}, "map.toml", "sensors[1]")
    r.string("message")
    assert r.array("axis_nominal", (3,), None) is None
    e = _err(r.finish)
    assert e.field == "sensors[1].axis_nomnal"
    assert "unknown key; did you mean 'axis_nominal'?" in str(e)
    # a required key missing while a near spelling is present says so
    r2 = Fields({"messgae": "M"}, "map.toml")
    assert "the file has 'messgae'" in str(_err(lambda: r2.string("message")))
    # accept: known keys that are not read
    r3 = Fields({"parity": 1}, "c.json")
    r3.finish(accept=("parity",))


def test_toml_lines_and_steps(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('schema = "rimu.sequence/1"\n\n[[steps]]\nouter_rate_w = 1\n'
                 '[[steps]]\nouter_rate_w = "x"\n')
    r = Fields.from_toml(p, "rimu.sequence/1")
    steps = r.tables("steps")
    e = _err(lambda: steps[1].with_step(2).number("outer_rate_w"))
    assert (e.line, e.step, e.field) == (6, 2, "outer_rate_w"), str(e)
    assert str(e).startswith(f"{p}:6, step 2, field 'outer_rate_w': expected a number")
    assert toml_key_line(p.read_text(), "schema") == 1
    assert toml_key_line(p.read_text(), "", "steps", 2) == 5


def test_schema_versions():
    assert check_schema({"schema": "rimu.calibration/1"}, "c.json",
                        ("rimu.calibration/2", "rimu.calibration/1")) == "rimu.calibration/1"
    e = _err(lambda: check_schema({"schema": "rimu.calibration/3"}, "c.json",
                                  ("rimu.calibration/2", "rimu.calibration/1")))
    assert "reads 'rimu.calibration/2' or 'rimu.calibration/1'" in str(e)
    assert "expected 'rimu.x/1'" in str(_err(lambda: check_schema({}, "c", "rimu.x/1")))
    assert check_schema({}, "c", "rimu.x/1", default="rimu.x/1") == "rimu.x/1"


def test_not_an_object(tmp_path):
    p = tmp_path / "a.json"
    p.write_text(json.dumps({"sub": [1]}))
    r = Fields.from_json(p)
    assert "expected an object, got [1]" in str(_err(lambda: r.mapping("sub")))
