"""Close the loop on calibration sessions: residual → effect → refit → error before and after.

``diagnose(session, cal)`` tests a library of candidate effects (the simulator's knobs,
temperature, a bias step, a periodic line, a re-mounting tilt, and the user's own) as
nested extensions of the calibration model, selects them forward at a stated α with a
Holm/Bonferroni correction over candidates × sensors, says "unexplained" (and where) when
structure remains that no candidate explains, refits and reports the error before and
after. :func:`calibration.calibrate_checked.calibrate_checked` (``rimu calibrate``) is the
calibration with this check in front of the coloured-noise model; it and :func:`diagnose`
have their verdict decided by one function, :func:`decide` (:mod:`.adequacy`). The verdict
is "adequate" only when the session could also have seen every library effect that moves a
parameter by 5 σ (:mod:`.detect`); "adequate within sequence limits" when only effects the
sequence itself cannot separate from the parameters could hide; otherwise "effects not ruled
out", with the sizes that could hide. Before any "adequate", every sensor's model must
predict the steps it did not see (:mod:`.holdout`); effect estimates beyond a plausible
bound of the sensor class are labelled as absorbing something else (:mod:`.bounds`). See
``docs/diagnose.md``.
"""

from calibration.diagnose.adequacy import decide
from calibration.diagnose.adequacy_text import format_adequacy
from calibration.diagnose.bounds import PHYSICAL_BOUNDS, bound_check, sensor_class
from calibration.diagnose.context import KindData, check_match, kind_data
from calibration.diagnose.library import (
    ENTRY_POINT_GROUP,
    Candidate,
    candidates,
    get_candidate,
    register_effect,
)
from calibration.diagnose.run import Diagnosis, assess, diagnose

__all__ = [
    "ENTRY_POINT_GROUP",
    "PHYSICAL_BOUNDS",
    "Candidate",
    "Diagnosis",
    "KindData",
    "assess",
    "bound_check",
    "candidates",
    "check_match",
    "decide",
    "diagnose",
    "format_adequacy",
    "get_candidate",
    "kind_data",
    "register_effect",
    "sensor_class",
]
