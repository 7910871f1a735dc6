"""Typed record of a Ferraris calibration (``extra.ferraris``): its settings and the χ² of
its static fits. Angles in rad (``_deg`` in the file)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fdi.extras.read import floats, matrix
from fdi.fileio import Fields
from fdi.units import DEG

__all__ = ["FerrarisRecord", "read_ferraris"]


# -- Ferraris ---------------------------------------------------------------------------
@dataclass(frozen=True)
class FerrarisRecord:
    """The settings and checks of a Ferraris calibration (``extra.ferraris``, degrees in the
    file).

    Attributes
    ----------
    rotation : float
        Nominal rotation about each axis (rad; imucal's −2π: clockwise seen from above).
    gravity : float
        Local gravity (m/s²).
    position_sd, angle_sd : float
        Stated sd of the static positions and of the rotation angles (rad).
    earth_rate_in_sd : bool
        The Earth rate is counted as an uncertainty of the gyro means.
    latitude : float or None
        Latitude (rad) whose vertical Earth rate was removed (None: not removed).
    g_sensitivity_raw_per_m_s2, g_sensitivity_raw_per_m_s2_sd : tuple of tuple of float
        Gyro g-sensitivity per sensor, raw units per m/s² (shape (n, 3)), and its sd.
    chi2_dof : dict of str to tuple of float
        Per sensor kind, χ²/dof of the static fits.
    chi2_dof_dof : int
        Their degrees of freedom per sensor.
    rotation_dof : int
        Spare degrees of freedom of the rotations.
    imucal : dict
        imucal's matrices from this fit (``K``, ``R``, ``b`` per kind in imucal's units),
        written as they come (not checked).
    """

    rotation: float
    gravity: float
    position_sd: float
    angle_sd: float
    earth_rate_in_sd: bool = True
    latitude: float | None = None
    g_sensitivity_raw_per_m_s2: tuple[tuple[float, ...], ...] = ()
    g_sensitivity_raw_per_m_s2_sd: tuple[tuple[float, ...], ...] = ()
    chi2_dof: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    chi2_dof_dof: int = 0
    rotation_dof: int = 0
    imucal: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The record ``extra.ferraris`` (angles in degrees; the fits' matrices and χ² as
        arrays, as the fit gives them: :func:`fdi.fileio.to_jsonable` writes them)."""
        lat = None if self.latitude is None else self.latitude / DEG
        return {"rotation_deg": self.rotation / DEG, "gravity_m_s2": self.gravity,
                "position_sd_deg": self.position_sd / DEG, "angle_sd_deg": self.angle_sd / DEG,
                "earth_rate_in_sd": self.earth_rate_in_sd, "latitude_deg": lat,
                "g_sensitivity_raw_per_m_s2": np.array(self.g_sensitivity_raw_per_m_s2, float),
                "g_sensitivity_raw_per_m_s2_sd": np.array(self.g_sensitivity_raw_per_m_s2_sd,
                                                          float),
                "chi2_dof": {**{k: np.array(v, float) for k, v in self.chi2_dof.items()},
                             "dof": self.chi2_dof_dof},
                "imucal": dict(self.imucal), "rotation_dof": self.rotation_dof}


def read_ferraris(r: Fields) -> FerrarisRecord | None:
    """``extra.ferraris`` (None when absent)."""
    if "ferraris" not in r:
        return None
    f = r.mapping("ferraris")
    lat = f.number("latitude_deg", None)
    c = f.mapping("chi2_dof", {})
    return FerrarisRecord(
        rotation=f.number("rotation_deg") * DEG, gravity=f.number("gravity_m_s2", positive=True),
        position_sd=f.number("position_sd_deg", nonnegative=True) * DEG,
        angle_sd=f.number("angle_sd_deg", nonnegative=True) * DEG,
        earth_rate_in_sd=f.boolean("earth_rate_in_sd", True),
        latitude=None if lat is None else lat * DEG,
        g_sensitivity_raw_per_m_s2=matrix(f, "g_sensitivity_raw_per_m_s2"),
        g_sensitivity_raw_per_m_s2_sd=matrix(f, "g_sensitivity_raw_per_m_s2_sd"),
        chi2_dof={k: floats(c, k) for k in c.keys() if k != "dof"},
        chi2_dof_dof=c.integer("dof", 0, lo=0), rotation_dof=f.integer("rotation_dof", 0, lo=0),
        imucal=f.free("imucal", {}))

