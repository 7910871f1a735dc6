"""Fixtures for the calibration tests: presets, simulated sessions, a tiny session.

Session-scoped and deterministic (fixed seeds); treat them as read-only.
"""

from __future__ import annotations

import pytest

from calibration.presets import preset
from calibration.sequence import Sequence, sequence_from_dict
from calibration.simulate import SessionNoise, simulate_session

TINY_SEQUENCE_DOC = {
    "schema": "rimu.sequence/1",
    "name": "tiny",
    "table_rate_dps": 90.0,
    "turns": 0.25,
    "position_duration_s": 0.5,
    "mount": "x_inner_z_up",
    "steps": [
        {"label": "level", "inner_deg": 0.0},
        {"label": "tilted", "inner_deg": 90.0},
        {"label": "+w table", "outer_rate_w": 1},
        {"label": "-w table", "outer_rate_w": -1},
    ],
}
"""Two 0.5 s positions and one rate pair of quarter turns at 90 °/s (1 s each): 300 samples."""


@pytest.fixture(scope="session")
def tetrad_preset():
    """(sequence, truth, noise) of ``tetrad-paper``."""
    return preset("tetrad-paper")


@pytest.fixture(scope="session")
def cone_preset():
    """(sequence, truth, noise) of ``cone-paper``."""
    return preset("cone-paper")


@pytest.fixture(scope="session")
def tetrad_session(tetrad_preset):
    """``tetrad-paper`` session, seed 0 (16 rate steps, 57 600 samples)."""
    seq, truth, noise = tetrad_preset
    return simulate_session(None, seq, truth, seed=0, noise=noise)


@pytest.fixture(scope="session")
def cone_session(cone_preset):
    """``cone-paper`` session, seed 0 (10 positions + 14 rate steps, 36 800 samples)."""
    seq, truth, noise = cone_preset
    return simulate_session(None, seq, truth, seed=0, noise=noise)


@pytest.fixture(scope="session")
def tiny_sequence() -> Sequence:
    """A 4-step sequence (2 positions, 1 rate pair), 300 samples at 100 Hz."""
    return sequence_from_dict(dict(TINY_SEQUENCE_DOC), "<tiny>")


@pytest.fixture(scope="session")
def tiny_session(tiny_sequence, cone_preset):
    """The cone-paper truth (gyros and accelerometers) over the tiny sequence, seed 0."""
    _, truth, _ = cone_preset
    return simulate_session(None, tiny_sequence, truth, seed=0)


@pytest.fixture(scope="session")
def noise_free():
    """A noise model with no noise at all."""
    return SessionNoise(white=False)
