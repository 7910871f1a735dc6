"""The adequacy and effect options of ``rimu calibrate`` (kept here so the command stays
a thin shell): ``--effects NAME,...`` and ``--alpha A``."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from fdi.adequacy import ADEQUATE, NOT_RULED_OUT, SUSPECTED, WITHIN_SEQUENCE_LIMITS
from fdi.effect_specs import builtin_names
from rimu.argtypes import probability

if TYPE_CHECKING:
    from calibration.session import Session
    from fdi.calfile import Calibration

__all__ = ["EFFECT_NAMES", "add_calibrate_options", "calibrate_with_check"]

EFFECT_NAMES = builtin_names()
"""The built-in candidate effects (:func:`fdi.effect_specs.builtin_names`, the order of
:func:`calibration.diagnose.library.candidates`; read from the specs, which import no
numerical library, so that ``rimu calibrate --help`` stays light)."""


def add_calibrate_options(p: argparse.ArgumentParser) -> None:
    """Add ``--effects`` and ``--alpha`` to the ``rimu calibrate`` parser."""
    p.add_argument("--effects", metavar="NAME,...",
                   help="fit these effects jointly with the calibration, on every sensor "
                        "they apply to (rimu.calibration/2 'effects'): "
                        + ", ".join(EFFECT_NAMES))
    p.add_argument("--alpha", type=probability(), default=0.01, metavar="A",
                   help="level of the model-adequacy check run before the noise model "
                        "(default 0.01); a suspected effect withholds the Gauss-Markov "
                        f"widening. Verdicts: {ADEQUATE}; {WITHIN_SEQUENCE_LIMITS} (nothing "
                        "found; what the sequence itself cannot separate from the parameters "
                        f"at 5 sigma is listed); {NOT_RULED_OUT} (nothing found, "
                        "but this session's noise could hide an effect that moves a "
                        f"parameter by 5 sigma: the sizes are listed); {SUSPECTED}")


def calibrate_with_check(session: Session, args: argparse.Namespace,
                         **kw: Any) -> Calibration:
    """``calibrate_checked`` with the command's ``--effects`` and ``--alpha``."""
    from calibration.calibrate_checked import calibrate_checked

    names = [x.strip() for x in (getattr(args, "effects", None) or "").split(",") if x.strip()]
    return calibrate_checked(session, alpha=getattr(args, "alpha", 0.01), effects=names, **kw)
