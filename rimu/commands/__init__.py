"""Sub-commands of the ``rimu`` CLI, one module each (see :mod:`rimu.cli`)."""

__all__: list[str] = []
