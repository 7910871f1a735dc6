"""Sensor geometry: measurement matrix H, named configurations and their validation.

Each row of ``H`` (shape ``(n, 3)``) is the unit input axis of one sensor in the master-body
(MB) frame (seed 001 Sec. II), so that the ideal outputs are ``y = H·ω`` (seed 000 Eq. 2).
Sensors are numbered from 1 in files, the CLI and messages (as in the papers) and from 0 in
arrays.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fdi.errors import ConfigError, FileFormatError
from fdi.fileio import Fields

__all__ = [
    "COLLINEAR_COS",
    "CONFIGURATION_SCHEMA",
    "NAMED_CONFIGURATIONS",
    "CollinearSensorsWarning",
    "Configuration",
    "cone6",
    "load_configuration",
    "tetrad",
    "triad",
]

CONFIGURATION_SCHEMA = "rimu.configuration/1"
COLLINEAR_COS = 0.9999
"""|cos| between two input axes above which they cannot be told apart (0.81° apart)."""

_UNIT_TOL = 1e-3


class CollinearSensorsWarning(UserWarning):
    """Two sensors measure (almost) the same axis: a fault on one looks like one on the other."""


@dataclass(frozen=True)
class Configuration:
    """A set of n ≥ 3 single-axis sensors.

    Attributes
    ----------
    name : str
        Configuration name (``"tetrad"``, ``"cone6"``, a file stem, ...).
    H : ndarray, shape (n, 3)
        Unit input axes in the MB frame, one row per sensor.
    sensor_names : tuple of str
        One name per sensor.
    groups : tuple of tuple of int
        Subsystems (0-based sensor indices), each calibrated with its own misalignment
        matrix M as in seed 000 Eq. 14 and seed 001 Eq. 1. Every sensor is in one group.
    """

    name: str
    H: np.ndarray
    sensor_names: tuple[str, ...]
    groups: tuple[tuple[int, ...], ...] = field(default=())

    def __post_init__(self) -> None:
        H = np.array(self.H, dtype=float)
        if H.ndim != 2 or H.shape[1] != 3:
            raise ConfigError(f"{self.name}: H must have shape (n, 3), got {H.shape}")
        n = H.shape[0]
        if not np.all(np.isfinite(H)):
            raise ConfigError(f"{self.name}: H has non-finite entries")
        norms = np.linalg.norm(H, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > _UNIT_TOL)
        if bad.size:
            i = int(bad[0])
            raise ConfigError(f"{self.name}: axis of sensor {i + 1} has norm {norms[i]:.6f}, "
                              "expected a unit vector")
        H = H / norms[:, None]
        if n >= 3 and np.linalg.matrix_rank(H, tol=1e-6) < 3:
            raise ConfigError(f"{self.name}: the {n} axes do not span 3-D space (rank < 3)")
        if n < 3:
            raise ConfigError(f"{self.name}: need at least 3 sensors, got {n}")
        H.setflags(write=False)
        object.__setattr__(self, "H", H)
        names = tuple(self.sensor_names) or tuple(f"s{i + 1}" for i in range(n))
        if len(names) != n:
            raise ConfigError(f"{self.name}: {len(names)} sensor names for {n} sensors")
        object.__setattr__(self, "sensor_names", names)
        groups = tuple(tuple(int(i) for i in g) for g in self.groups) or (tuple(range(n)),)
        flat = sorted(i for g in groups for i in g)
        if flat != list(range(n)):
            raise ConfigError(f"{self.name}: groups must contain every sensor exactly once")
        object.__setattr__(self, "groups", groups)
        for i, j in self.collinear_pairs():
            warnings.warn(f"{self.name}: sensors {i + 1} and {j + 1} are collinear "
                          "(cannot be told apart)", CollinearSensorsWarning, stacklevel=3)

    @property
    def n(self) -> int:
        """Number of sensors."""
        return int(self.H.shape[0])

    def collinear_pairs(self) -> list[tuple[int, int]]:
        """Pairs (i, j), 0-based, whose axes are parallel or antiparallel."""
        c = np.abs(self.H @ self.H.T)
        return [(i, j) for i in range(self.n) for j in range(i + 1, self.n)
                if c[i, j] > COLLINEAR_COS]

    def group_of(self, i: int) -> int:
        """Index of the group that holds sensor ``i`` (0-based)."""
        for k, g in enumerate(self.groups):
            if i in g:
                return k
        raise ConfigError(f"sensor {i + 1} is in no group")  # unreachable after validation


def tetrad() -> Configuration:
    """Four gyros on a tetrahedron, seed 000 Eq. 1 (α = 54.736°).

    Subsystems as seed 000 Eq. 14: sensors 1-3 (M₁) and sensor 4 (M₂).
    """
    s3, s6, s2 = math.sqrt(3.0), math.sqrt(6.0), math.sqrt(2.0)
    H = [[1 / s3, 0.0, s6 / 3],               # seed 000 Eq. 1
         [1 / s3, s2 / 2, -s6 / 6],
         [1 / s3, -s2 / 2, -s6 / 6],
         [1.0, 0.0, 0.0]]
    return Configuration("tetrad", np.array(H), ("g1", "g2", "g3", "g4"), ((0, 1, 2), (3,)))


def cone6() -> Configuration:
    """Orthogonal-cone configuration of six sensors, seed 001 Eq. 18.

    Two tilted orthogonal sub-IMUs: sensors 1-3 and 4-6 (seed 001 Eq. 1).
    """
    a, b, c, d = math.sqrt(2.0 / 3.0), 1 / math.sqrt(6.0), 1 / math.sqrt(2.0), 1 / math.sqrt(3.0)
    H = [[a, 0.0, -d],                         # seed 001 Eq. 18
         [-b, -c, -d],
         [-b, c, -d],
         [-a, 0.0, -d],
         [b, c, -d],
         [b, -c, -d]]
    names = ("x1", "y1", "z1", "x2", "y2", "z2")
    return Configuration("cone6", np.array(H), names, ((0, 1, 2), (3, 4, 5)))


def triad() -> Configuration:
    """Three orthogonal sensors along the MB axes: no redundancy, reconstruction only."""
    return Configuration("triad", np.eye(3), ("x", "y", "z"), ((0, 1, 2),))


NAMED_CONFIGURATIONS = {"cone6": cone6, "tetrad": tetrad, "triad": triad}
"""Built-in configurations by name."""


def load_configuration(spec: str | Path) -> Configuration:
    """A built-in configuration by name, or one read from a TOML file.

    The TOML file holds an optional ``schema = "rimu.configuration/1"``, an optional
    ``name`` and one ``[[sensors]]`` table per sensor with ``axis = [x, y, z]`` (unit
    vector, MB frame), an optional ``name`` and an optional ``group`` (any string or
    integer; sensors with the same group share one misalignment matrix M). For example::

        schema = "rimu.configuration/1"
        name = "skewed-five"
        [[sensors]]
        name = "a"
        axis = [0.0, 0.0, 1.0]
        group = 1

    The older table name ``[[sensor]]`` is still read, with a :class:`DeprecationWarning`.

    Raises
    ------
    FileFormatError
        The file is missing, not TOML, a field is wrong or unknown (the message names it).
    ConfigError
        The geometry is invalid (non-unit axis, rank < 3, fewer than 4 sensors in a file).
    """
    key = str(spec)
    if key in NAMED_CONFIGURATIONS:
        return NAMED_CONFIGURATIONS[key]()
    path = Path(spec)
    if not path.is_file():
        raise FileFormatError(str(path), "no such configuration file; built-in names are "
                              + ", ".join(sorted(NAMED_CONFIGURATIONS)))
    r = Fields.from_toml(path, CONFIGURATION_SCHEMA, schema_default=CONFIGURATION_SCHEMA)
    table = r.table_name("sensors")
    sensors = r.tables(table)
    if len(sensors) < 4:
        raise ConfigError(f"{path}: a redundant set needs n >= 4 sensors, got {len(sensors)}")
    axes, names, group_keys = [], [], []
    for i, s in enumerate(sensors, start=1):
        axes.append(s.array("axis", (3,)))
        norm = float(np.linalg.norm(axes[-1]))
        if abs(norm - 1.0) > _UNIT_TOL:
            raise s.error("axis", f"axis norm is {norm:.6f}, expected 1")
        names.append(s.string("name", f"s{i}"))
        g = s.get("group", 0)
        if isinstance(g, bool) or not isinstance(g, str | int):
            raise s.error("group", f"expected a string or an integer, got {g!r}")
        group_keys.append(g)
        s.finish()
    name = r.string("name", path.stem)
    r.finish()
    order: dict[object, list[int]] = {}
    for i, g in enumerate(group_keys):
        order.setdefault(g, []).append(i)
    groups = tuple(tuple(v) for v in order.values())
    try:
        return Configuration(name, np.array(axes), tuple(names), groups)
    except ConfigError as exc:
        raise FileFormatError(str(path), str(exc).removeprefix(f"{name}: ")) from None
