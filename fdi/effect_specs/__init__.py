"""One specification per sensor effect: its units, inputs, regressor, simulator knob,
in-flight candidate and run-time form (:mod:`.spec`), the built-in effects
(:mod:`.builtin`, the only module that names them) and the registry (:mod:`.registry`).

The simulator (:mod:`calibration.effects`, :mod:`calibration.simulate`), the session and
in-flight diagnoses (:mod:`calibration.diagnose.library`,
:mod:`calibration.inflight.diagnose`) and the run-time compensator (:mod:`fdi.effects`)
derive their forms from these specs; ``docs/effects.md`` shows how to add one.
"""

from fdi.effect_specs.builtin import (
    BUILTIN,
    INPUT_LACKING,
    RUNTIME_INPUTS,
    TEMP_RISE_DEGC,
    TEMP_START_DEGC,
    TEMP_TAU_S,
    WARMUP_FLIGHT_TAU_S,
    WARMUP_TAU_S,
    temperature_profile,
)
from fdi.effect_specs.registry import (
    ENTRY_POINT_GROUP,
    builtin_names,
    effect_specs,
    entry_point_objects,
    get_spec,
    load_entry_points,
    register_spec,
)
from fdi.effect_specs.spec import (
    BIAS_UNITS,
    EffectSpec,
    FlightForm,
    FlightInputs,
    RuntimeForm,
    SessionInputs,
    SimulatorForm,
)

__all__ = [
    "BIAS_UNITS",
    "BUILTIN",
    "ENTRY_POINT_GROUP",
    "INPUT_LACKING",
    "RUNTIME_INPUTS",
    "TEMP_RISE_DEGC",
    "TEMP_START_DEGC",
    "TEMP_TAU_S",
    "WARMUP_FLIGHT_TAU_S",
    "WARMUP_TAU_S",
    "EffectSpec",
    "FlightForm",
    "FlightInputs",
    "RuntimeForm",
    "SessionInputs",
    "SimulatorForm",
    "builtin_names",
    "effect_specs",
    "entry_point_objects",
    "get_spec",
    "load_entry_points",
    "register_spec",
    "temperature_profile",
]
