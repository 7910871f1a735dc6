"""Flight folders with IMU groups and channels kept beside the gyros (accelerometers,
temperatures): round trip, backward compatibility and precise errors."""

import json

import numpy as np
import pytest

from fdi.errors import ConfigError, FileFormatError
from replay.flight_data import AuxChannels, Flight, concat_flights
from replay.flight_io import AUX_FILE, FLIGHT_SCHEMA, load_flight_dir, save_flight_dir


def _two_imu_flight(N=50, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / 50.0
    names = tuple(f"imu{k}.{a}" for k in (1, 2) for a in "xyz")
    raw = rng.standard_normal((N, 6))
    valid = np.ones((N, 6), bool)
    valid[7, 3:] = False                      # IMU 2 missed one sample
    raw[~valid] = np.nan
    kinds = ("accel",) * 6 + ("temperature",) * 2
    anames = (*names, "imu1", "imu2")
    imus = tuple(n.split(".")[0] for n in anames)
    vals = np.column_stack([9.81 + rng.standard_normal((N, 6)), 30 + rng.random((N, 2))])
    avalid = np.ones_like(vals, bool)
    avalid[::5, 7] = False                    # temperature logged at a fifth of the rate
    vals[~avalid] = np.nan
    aux = AuxChannels(kinds, anames, imus, vals, avalid)
    return Flight(t=t, raw=raw, valid=valid, sample_rate_hz=50.0, sensor_names=names,
                  raw_unit="rad/s", imu=tuple(n.split(".")[0] for n in names), aux=aux,
                  source="test")


def test_round_trip_with_imu_groups_and_aux(tmp_path):
    fl = _two_imu_flight()
    save_flight_dir(fl, tmp_path / "f")
    man = json.loads((tmp_path / "f" / "manifest.json").read_text())
    assert man["schema"] == FLIGHT_SCHEMA
    assert man["columns"] == ["t", *fl.sensor_names]          # samples.csv as in /1
    assert man["aux"]["file"] == AUX_FILE
    assert [c["unit"] for c in man["aux"]["channels"]] == ["m/s^2"] * 6 + ["degC"] * 2
    g = load_flight_dir(tmp_path / "f")
    np.testing.assert_array_equal(g.raw, fl.raw)
    np.testing.assert_array_equal(g.valid, fl.valid)
    assert g.imu == fl.imu and g.imu_groups() == {"imu1": [0, 1, 2], "imu2": [3, 4, 5]}
    assert g.aux.kinds == fl.aux.kinds and g.aux.names == fl.aux.names
    assert g.aux.imu == fl.aux.imu
    np.testing.assert_array_equal(g.aux.values, fl.aux.values)
    np.testing.assert_array_equal(g.aux.valid, fl.aux.valid)
    acc = g.aux.select("accel")
    assert acc.m == 6 and acc.names[3] == "imu2.x"
    np.testing.assert_array_equal(acc.values, fl.aux.values[:, :6])
    # saving the same folder without aux removes the stale aux.csv
    save_flight_dir(Flight(t=fl.t, raw=fl.raw, valid=fl.valid, sample_rate_hz=50.0,
                           sensor_names=fl.sensor_names), tmp_path / "f")
    assert not (tmp_path / "f" / AUX_FILE).exists()
    h = load_flight_dir(tmp_path / "f")
    assert h.aux is None and h.imu == ()


def test_plain_folder_has_no_new_fields(tmp_path):
    """A flight without groups or aux writes exactly the fields of the original /1 format."""
    fl = _two_imu_flight()
    plain = Flight(t=fl.t, raw=fl.raw, valid=fl.valid, sample_rate_hz=50.0,
                   sensor_names=fl.sensor_names)
    save_flight_dir(plain, tmp_path / "p")
    man = json.loads((tmp_path / "p" / "manifest.json").read_text())
    assert set(man) == {"schema", "sample_rate_hz", "kind", "sensor_names", "raw_unit",
                        "columns", "samples", "samples_file", "source"}


def test_concat_keeps_aux():
    fl = _two_imu_flight(N=40)
    parts = [Flight(**{**fl.__dict__, "t": fl.t[a:b], "raw": fl.raw[a:b],
                       "valid": fl.valid[a:b], "aux": fl.aux.slice(slice(a, b))})
             for a, b in ((0, 13), (13, 40))]
    j = concat_flights(parts)
    np.testing.assert_array_equal(j.aux.values, fl.aux.values)
    np.testing.assert_array_equal(j.aux.valid, fl.aux.valid)
    with pytest.raises(ConfigError, match="different aux channels"):
        concat_flights([parts[0], Flight(**{**parts[1].__dict__, "aux": None})])


def test_aux_channels_validate():
    v = np.zeros((3, 2))
    with pytest.raises(ConfigError, match="kind 'magnetic'"):
        AuxChannels(("accel", "magnetic"), ("a", "b"), ("", ""), v, v > 0)
    with pytest.raises(ConfigError, match="appears twice"):
        AuxChannels(("accel", "accel"), ("a", "a"), ("", ""), v, v > 0)
    with pytest.raises(ConfigError, match=r"must both be \(N, 2\)"):
        AuxChannels(("accel", "accel"), ("a", "b"), ("", ""), v[:, :1], v[:, :1] > 0)


def _edit(d, fn):
    m = json.loads((d / "manifest.json").read_text())
    fn(m)
    (d / "manifest.json").write_text(json.dumps(m))


@pytest.mark.parametrize(("edit", "words"), [
    (lambda m: m.update(imu=["imu1"]), "field 'imu': expected a list of 6 strings"),
    (lambda m: m["aux"]["channels"][0].update(unit="g"),
     "field 'aux.channels[0]': unit 'g': accel channels are stored in 'm/s^2'"),
    (lambda m: m["aux"]["channels"][1].update(kind="mag"),
     "field 'aux.channels[1]': kind 'mag' is not one of"),
    (lambda m: m["aux"].update(channels=[]), "field 'aux': expected"),
    (lambda m: m["aux"].update(file="../x.csv"), "field 'aux.file': expected a file name"),
    (lambda m: m["aux"].update(file="gone.csv"), "gone.csv, field 'aux.file': cannot read"),
])
def test_manifest_errors_are_precise(tmp_path, edit, words):
    save_flight_dir(_two_imu_flight(), tmp_path / "f")
    _edit(tmp_path / "f", edit)
    with pytest.raises(FileFormatError) as ei:
        load_flight_dir(tmp_path / "f")
    assert words in str(ei.value), str(ei.value)


def test_aux_csv_errors_are_precise(tmp_path):
    d = tmp_path / "f"
    save_flight_dir(_two_imu_flight(), d)
    lines = (d / AUX_FILE).read_text().splitlines()
    cells = lines[5].split(",")
    cells[0] = "0.0801"                                  # another time on line 6
    (d / AUX_FILE).write_text("\n".join([*lines[:5], ",".join(cells), *lines[6:]]) + "\n")
    with pytest.raises(FileFormatError, match=r"aux\.csv:6, field 't': times differ"):
        load_flight_dir(d)
    (d / AUX_FILE).write_text("\n".join(lines[:-3]) + "\n")     # truncated
    with pytest.raises(FileFormatError, match=r"aux\.csv:49, field 't': times differ .*47 rows"):
        load_flight_dir(d)
