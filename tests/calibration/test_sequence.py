"""Test sequences: the paper tables derived through the one table model, and the loader."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.sequence import load_sequence, sequence_from_dict
from calibration.simulate import SessionNoise, simulate_session
from calibration.turntable import earth_rate_n
from fdi.errors import FileFormatError
from fdi.units import DPS

C30, S30 = math.cos(math.radians(30)), math.sin(math.radians(30))

# seed 000 Table 1 "Input rate" columns, multiples of w, typed from the paper (rows 1..16)
SEED000_TABLE1 = [(1, 0, 0), (-1, 0, 0), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0),
                  (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (0, 0, 1), (0, 0, -1),
                  (0, C30, S30), (0, -C30, -S30), (0, C30, -S30), (0, -C30, S30)]
# what the one model gives for rows 7, 8, 11, 12 (inner angles of Table 1, sign-flipped)
SEED000_DERIVED_DISAGREEING = {7: (0, C30, -S30), 8: (0, 1, 0), 11: (0, 0, -1),
                               12: (0, 0, 1)}
H45 = math.sqrt(0.5)
# seed 001 Table 1 (gravity in the body, multiples of g) and Table 2 (multiples of w)
SEED001_TABLE1 = [(0, 0, -1), (0, -1, 0), (0, 0, 1), (0, 1, 0), (1, 0, 0), (-1, 0, 0),
                  (-H45, H45, 0), (H45, H45, 0), (-H45, 0, H45), (H45, 0, H45)]
SEED001_TABLE2 = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
                  (-S30, -C30, 0), (S30, C30, 0), (-S30, C30, 0), (S30, -C30, 0),
                  (H45, -H45, 0), (-H45, H45, 0), (H45, H45, 0), (-H45, -H45, 0)]


def test_tetrad_table1_derived_inputs():
    seq = load_sequence("tetrad-paper")
    assert len(seq.steps) == 16
    derived = seq.derived_inputs()
    for k, st in enumerate(seq.steps):
        row = k + 1
        assert st.printed == pytest.approx(SEED000_TABLE1[k], abs=1e-12), f"row {row} printed"
        want = SEED000_DERIVED_DISAGREEING.get(row, SEED000_TABLE1[k])
        np.testing.assert_allclose(derived[k], want, atol=1e-12, err_msg=f"row {row}")
        # the file flags exactly the rows whose printed input contradicts the kinematics
        assert st.printed_agrees == (row not in SEED000_DERIVED_DISAGREEING), f"row {row}"
        assert st.kind == "rate"
        assert st.duration_s == pytest.approx(36.0), f"row {row}: one turn at 10 deg/s"
    assert seq.pairs() == tuple((i, i + 1) for i in range(1, 17, 2))


def test_cone_tables_derived_inputs():
    seq = load_sequence("cone-paper")
    assert [s.kind for s in seq.steps] == ["position"] * 10 + ["rate"] * 14
    derived = seq.derived_inputs()
    np.testing.assert_allclose(derived[:10], SEED001_TABLE1, atol=1e-12,
                               err_msg="seed 001 Table 1 (gravity vector)")
    np.testing.assert_allclose(derived[10:], SEED001_TABLE2, atol=1e-12,
                               err_msg="seed 001 Table 2")
    assert all(s.printed_agrees for s in seq.steps)
    # specific force of the home position is +g along z (z Up)
    np.testing.assert_allclose(seq.steps[0].up_body(), [0, 0, 1], atol=1e-12)
    assert seq.table_rate_dps == pytest.approx(30.0)
    assert [s.duration_s for s in seq.rate_steps()] == pytest.approx([12.0] * 14)
    assert [s.duration_s for s in seq.position_steps()] == pytest.approx([20.0] * 10)
    assert seq.pairs() == tuple((i, i + 1) for i in range(11, 25, 2))


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_excitation_full_rank(name):
    """The rate pairs span 3-D (seed 000 Eq. 18 R) and positions + 1 span 4-D (seed 001 Eq. 8)."""
    seq = load_sequence(name)
    d = seq.derived_inputs()
    R = np.array([d[a - 1] - d[b - 1] for a, b in seq.pairs()])
    assert np.linalg.matrix_rank(R) == 3
    pos = [s.index - 1 for s in seq.position_steps()]
    if pos:
        S = np.column_stack([d[pos], np.ones(len(pos))])
        assert np.linalg.matrix_rank(S) == 4


@pytest.mark.parametrize("name", ["tetrad-paper", "cone-paper"])
def test_session_inputs_follow_the_sequence(name):
    """Session.inputs() (the one model) gives each rate step's derived table rate, and Earth
    rate averages to its vertical part over each whole outer-axis turn (seed 000 Eq. 20)."""
    seq = load_sequence(name)
    lat = -23.2
    from calibration.presets import preset
    _, truth, _ = preset(name)
    s = simulate_session(None, seq, truth, seed=0, noise=SessionNoise(white=False),
                         latitude_deg=lat)
    wt, we, _ = s.inputs()
    w_up = earth_rate_n(math.radians(lat))[2]
    for st in seq.steps:
        m = s.step == st.index
        if st.kind == "rate":
            np.testing.assert_allclose(wt[m], np.tile(st.body_rate(), (m.sum(), 1)),
                                       atol=1e-15, err_msg=f"step {st.index}")
            np.testing.assert_allclose(np.linalg.norm(st.body_rate()), seq.table_rate,
                                       rtol=1e-12)
        if st.kind == "rate" and st.inner_rate == 0.0:
            np.testing.assert_allclose(we[m].mean(0), w_up * st.up_body(), atol=1e-18,
                                       err_msg=f"step {st.index}: Earth rate over a turn")


def _doc(**steps_and_top):
    doc = {"schema": "rimu.sequence/1", "table_rate_dps": 10.0,
           "steps": [{"outer_rate_w": 1}, {"outer_rate_w": -1}]}
    doc.update(steps_and_top)
    return doc


def test_default_pairing_and_overrides(tmp_path):
    seq = sequence_from_dict(_doc(steps=[{"inner_deg": 0.0}, {"outer_rate_w": 1},
                                        {"outer_rate_dps": -10.0}, {"inner_rate_w": 2},
                                        {"inner_rate_w": -2, "duration_s": 5.0}]))
    assert seq.pairs() == ((2, 3), (4, 5))
    assert seq.steps[0].kind == "position" and seq.steps[0].pair is None
    assert seq.steps[0].duration_s == 20.0
    assert seq.steps[3].duration_s == pytest.approx(18.0)       # one turn at 20 deg/s
    assert seq.steps[4].duration_s == 5.0
    p = tmp_path / "s.toml"
    p.write_text('schema = "rimu.sequence/1"\ntable_rate_dps = 10.0\nturns = 2\n'
                 '[[steps]]\nouter_rate_w = 1\n[[steps]]\nouter_rate_w = -1\n')
    s2 = load_sequence(p, table_rate_dps=20.0, turns=1)
    assert s2.steps[0].outer_rate == pytest.approx(20.0 * DPS)
    assert s2.steps[0].duration_s == pytest.approx(18.0)
    assert load_sequence(p).steps[1].duration_s == pytest.approx(72.0)


BAD = [
    ("unknown top key", {"speed": 1}, None, "speed"),
    ("unknown step key", {"steps": [{"outer_rate_deg": 1}]}, 1, "outer_rate_deg"),
    ("both rate keys", {"steps": [{"outer_rate_w": 1, "outer_rate_dps": 10}]}, 1,
     "outer_rate_w"),
    ("non-number", {"steps": [{"inner_deg": "ten"}]}, 1, "inner_deg"),
    ("rate without rate", {"steps": [{"kind": "rate"}]}, 1, "kind"),
    ("position with rate", {"steps": [{"kind": "position", "inner_rate_w": 1}]}, 1, "kind"),
    ("bad kind", {"steps": [{"kind": "spin", "inner_rate_w": 1}]}, 1, "kind"),
    ("unknown mount", {"steps": [{"outer_rate_w": 1}, {"mount": "upside", "outer_rate_w": -1}]},
     2, "mount"),
    ("both axes turn, turns", {"steps": [{"outer_rate_w": 1, "inner_rate_w": 1}]}, 1,
     "duration_s"),
    ("turns and duration", {"steps": [{"outer_rate_w": 1, "turns": 1, "duration_s": 3}]}, 1,
     "turns"),
    ("negative duration", {"steps": [{"outer_rate_w": 1, "duration_s": -3}]}, 1, "duration_s"),
    ("pair not mutual", {"steps": [{"outer_rate_w": 1, "pair": 2}, {"outer_rate_w": -1},
                                  {"outer_rate_w": -1, "pair": 1}]}, 1, "pair"),
    ("pair to position", {"steps": [{"outer_rate_w": 1, "pair": 2}, {"pair": 1}]}, 1, "pair"),
    ("pair out of range", {"steps": [{"outer_rate_w": 1, "pair": 9}]}, 1, "pair"),
    ("printed not 3", {"steps": [{"outer_rate_w": 1, "printed": [1, 0]}]}, 1, "printed"),
    ("wrong schema", {"schema": "rimu.session/1"}, None, "schema"),
    ("wrong version", {"schema": "rimu.sequence/9"}, None, "schema"),
    ("no steps", {"steps": []}, None, "steps"),
    ("bad table rate", {"table_rate_dps": 0}, None, "table_rate_dps"),
]


@pytest.mark.parametrize(("what", "change", "step", "field"), BAD, ids=[b[0] for b in BAD])
def test_loader_errors_name_step_and_field(tmp_path, what, change, step, field):
    doc = _doc(**change)
    with pytest.raises(FileFormatError) as ei:
        sequence_from_dict(doc, "seq.toml")
    e = ei.value
    assert e.path == "seq.toml", what
    assert e.step == step, f"{what}: {e}"
    assert e.field == field, f"{what}: {e}"
    assert "seq.toml" in str(e)


def test_loader_file_errors(tmp_path):
    with pytest.raises(FileFormatError, match="no such sequence file"):
        load_sequence(tmp_path / "missing.toml")
    p = tmp_path / "bad.toml"
    p.write_text("[[step]\nouter_rate_w = 1\n")
    with pytest.raises(FileFormatError, match="not valid TOML"):
        load_sequence(p)


def test_old_step_table_name_still_loads_with_a_deprecation_warning(tmp_path):
    """Issue 10: one spelling of arrays of tables across formats ([[steps]] like
    [[sensors]] and [[faults]]); the old [[step]] keeps working, with a warning."""
    p = tmp_path / "old.toml"
    p.write_text('schema = "rimu.sequence/1"\n[[step]]\nouter_rate_w = 1\n'
                 '[[step]]\nouter_rate_w = -1\n')
    with pytest.warns(DeprecationWarning, match=r"\[\[step\]\] is deprecated"):
        seq = load_sequence(p)
    assert seq.pairs() == ((1, 2),)


def test_errors_in_a_file_name_the_line(tmp_path):
    p = tmp_path / "typo.toml"
    p.write_text('schema = "rimu.sequence/1"\n[[steps]]\nouter_rate_w = 1\n'
                 '[[steps]]\nouter_rate_w = -1\nmonut = "x_inner_y_up"\n')
    with pytest.raises(FileFormatError) as ei:
        load_sequence(p)
    e = ei.value
    assert (e.line, e.step, e.field) == (6, 2, "monut"), str(e)
    assert "did you mean 'mount'?" in str(e)
