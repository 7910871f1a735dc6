"""The effect registry: built-in specs first, then users' (in-process or entry points).

The one registry of effects and the one reader of the entry-point group
:data:`ENTRY_POINT_GROUP`. Users add an :class:`~fdi.effect_specs.spec.EffectSpec` with
:func:`register_spec` or through the group (an entry point names a spec, a list of them or
a callable returning either); the diagnosis, the simulator and the monitor then treat it as
a built-in one (its forms that are None it does not have). :func:`load_entry_points` reads
the group, registers its specs and hands back what else it names (a
``calibration.diagnose.Candidate``, a regressor the diagnosis alone knows), which the
diagnosis keeps beside the specs (``calibration.diagnose.library``).
"""

from __future__ import annotations

from importlib import metadata

from fdi.effect_specs.builtin import BUILTIN
from fdi.effect_specs.spec import EffectSpec
from fdi.errors import ConfigError

__all__ = ["ENTRY_POINT_GROUP", "builtin_names", "effect_specs", "entry_point_objects",
           "get_spec", "load_entry_points", "register_spec"]

ENTRY_POINT_GROUP = "rimu.effects"
"""The entry-point group of user effects."""

_SPECS: dict[str, EffectSpec] = {s.name: s for s in BUILTIN}
_LOADED = False


def register_spec(spec: EffectSpec) -> EffectSpec:
    """Add a spec (or replace the one of the same name); returns it.

    Raises
    ------
    ConfigError
        Not an :class:`EffectSpec`.
    """
    if not isinstance(spec, EffectSpec):
        raise ConfigError(f"register_spec: expected an EffectSpec, got {type(spec).__name__}")
    _SPECS[spec.name] = spec
    return spec


def entry_point_objects(entry_points: object = None, *, strict: bool = True
                        ) -> list[object]:
    """The objects the group's entry points name (callables called, lists flattened).

    ``strict`` False skips an entry point that cannot be loaded.

    Raises
    ------
    ConfigError
        ``strict``: an entry point that cannot be loaded (named).
    """
    eps = metadata.entry_points(group=ENTRY_POINT_GROUP) if entry_points is None \
        else entry_points
    out: list[object] = []
    for ep in eps:
        try:
            obj = ep.load()
            if callable(obj) and not isinstance(obj, EffectSpec) \
                    and not hasattr(obj, "regressor"):
                obj = obj()
        except Exception as exc:  # a broken plug-in must name itself
            if not strict:
                continue
            raise ConfigError(f"entry point {ep.name!r} of group {ENTRY_POINT_GROUP}: cannot "
                              f"load {ep.value} ({exc})") from None
        out += list(obj) if isinstance(obj, list | tuple) else [obj]
    return out


def load_entry_points(*, strict: bool = True) -> list[object]:
    """Read the entry-point group: register every spec it names (:func:`register_spec`)
    and return the other objects, in order.

    ``strict`` False skips an entry point that cannot be loaded.

    Raises
    ------
    ConfigError
        ``strict``: an entry point that cannot be loaded (named).
    """
    others: list[object] = []
    for obj in entry_point_objects(strict=strict):
        if isinstance(obj, EffectSpec):
            register_spec(obj)
        else:
            others.append(obj)
    return others


def _load() -> None:
    global _LOADED
    if _LOADED:
        return
    _LOADED = True
    # a broken plug-in is skipped here (the knob list and the monitor go on without it);
    # the diagnosis loads the group strictly and names it
    load_entry_points(strict=False)


def effect_specs() -> tuple[EffectSpec, ...]:
    """Every registered spec: built-in ones in their order, then users'."""
    _load()
    return tuple(_SPECS.values())


def get_spec(name: str) -> EffectSpec | None:
    """The spec of that name, None when none is registered."""
    _load()
    return _SPECS.get(name)


def builtin_names() -> tuple[str, ...]:
    """Names of the built-in effects, in their order."""
    return tuple(s.name for s in BUILTIN)
