"""Names and one-line descriptions of the calibration presets (no numerical imports: the
help of ``rimu simulate calibration`` lists them). The presets are in
:mod:`calibration.presets`."""

__all__ = ["PRESETS"]

PRESETS: dict[str, str] = {
    "cone-paper": "seed 001: MEMS orthogonal cone, Table 3 values, 30 deg/s, latitude 37.5",
    "tetrad-paper": "seed 000: FOG tetrad, Table 2 and Eq. 26 values, 10 deg/s, "
                    "latitude -23.2",
}
"""Preset names and one-line descriptions."""
