"""Export of the monitor to other languages: :func:`generate_c` (``rimu export c``)."""

from fdi.export.c import (
    MAX_RING,
    MAX_TABLE_BYTES,
    PRECISIONS,
    CModule,
    generate_c,
    reachable_sets,
    write_c,
)

__all__ = ["MAX_RING", "MAX_TABLE_BYTES", "PRECISIONS", "CModule", "generate_c",
           "reachable_sets", "write_c"]
