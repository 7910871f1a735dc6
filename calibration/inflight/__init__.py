"""In-flight calibration of a set of IMUs against itself, and the diagnosis of a flight's
parity residual (see docs/inflight.md).

Modules: :mod:`.regression` (stacked least squares, HAC covariance), :mod:`.segments`
(segments to leave out), :mod:`.fit` (alignment, bias, time offset, excitation check),
:mod:`.calfile` (the ``rimu.calibration/1`` file), :mod:`.diagnose` (effects in the
residual).
"""

from calibration.inflight.calfile import calibration_from_fit
from calibration.inflight.diagnose import diagnose_flight
from calibration.inflight.fit import InflightFit, fit_inflight

__all__ = ["InflightFit", "calibration_from_fit", "diagnose_flight", "fit_inflight"]
