"""The model-adequacy verdicts of a calibration file, best first.

A calibration's ``adequacy`` entry (``rimu.calibration/*``) carries one of these strings
as ``verdict``; they are part of the file format, so old files keep loading only while the
strings stay as they are. Best to worst:

- ``"adequate"``: nothing found, and the session would have found every library effect
  that moves a parameter by 5 σ;
- ``"adequate within sequence limits"``: nothing found, and the session would have found
  every such effect except those the sequence itself cannot separate from the parameters
  (hidden even under white noise of the session's level; listed as ``sequence_limits``);
- ``"effects not ruled out"``: nothing found, but this session's noise could hide such an
  effect (listed as ``not_ruled_out``);
- ``"effects suspected"``: an effect or unexplained structure was found, or the model did
  not predict steps it had not seen (the held-out check); listed under ``where``.

The verdict is decided in one place, :func:`calibration.diagnose.adequacy.decide`, from the
evidence the record holds: the worst verdict whose evidence is present wins.
"""

from __future__ import annotations

__all__ = ["ADEQUATE", "NOT_RULED_OUT", "SUSPECTED", "VERDICTS", "WITHIN_SEQUENCE_LIMITS"]

ADEQUATE = "adequate"
WITHIN_SEQUENCE_LIMITS = "adequate within sequence limits"
NOT_RULED_OUT = "effects not ruled out"
SUSPECTED = "effects suspected"
VERDICTS = (ADEQUATE, WITHIN_SEQUENCE_LIMITS, NOT_RULED_OUT, SUSPECTED)
"""Every verdict, best first (the order :func:`calibration.diagnose.adequacy.decide`
ranks them in)."""
