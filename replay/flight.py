"""Flights: kept for ``from replay.flight import ...``; the code lives in three modules.

- :mod:`replay.flight_data`: the :class:`Flight` record (with IMU groups and channels kept
  beside the monitored sensors, :class:`AuxChannels`);
- :mod:`replay.flight_sim`: the flight simulation (:func:`simulate_flight`, staged
  :func:`iter_flight`);
- :mod:`replay.flight_io`: the ``rimu.flight/1`` folder and the truth sidecar.
"""

from replay.flight_data import AuxChannels, Flight, concat_flights
from replay.flight_io import (
    FLIGHT_SCHEMA,
    load_flight_dir,
    read_truth_sidecar,
    save_flight_dir,
    write_truth_sidecar,
)
from replay.flight_sim import (
    CHUNK_SAMPLES,
    FLIGHT_TRUTH_SCHEMA,
    TrueModel,
    draw_true_model,
    iter_flight,
    simulate_flight,
    true_model_from_calibration,
)

__all__ = [
    "CHUNK_SAMPLES",
    "FLIGHT_SCHEMA",
    "FLIGHT_TRUTH_SCHEMA",
    "AuxChannels",
    "Flight",
    "TrueModel",
    "concat_flights",
    "draw_true_model",
    "iter_flight",
    "load_flight_dir",
    "read_truth_sidecar",
    "save_flight_dir",
    "simulate_flight",
    "true_model_from_calibration",
    "write_truth_sidecar",
]
