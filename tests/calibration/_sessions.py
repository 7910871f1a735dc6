"""Sessions for the calibration tests, from the presets and the product simulator."""

import dataclasses

from calibration.presets import preset
from calibration.simulate import SessionNoise, simulate_session


def session(name, seed=0, *, white=True, **kw):
    """(session, truth) of a preset; ``white=False`` gives noise-free outputs."""
    seq, truth, noise = preset(name)
    s = simulate_session(None, seq, truth, seed=seed,
                         noise=noise if white else SessionNoise(white=False), **kw)
    return s, truth


def with_changes(s, **kw):
    """A copy of a session with some fields replaced."""
    return dataclasses.replace(s, **kw)


def shift_outer(s, delta_rad):
    """The same samples, table outer angles recorded ``delta_rad`` off."""
    return dataclasses.replace(s, outer=s.outer + delta_rad)


__all__ = ["session", "shift_outer", "with_changes"]
