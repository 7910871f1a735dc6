"""The monitor in other forms: a self-contained C99 module (:mod:`fdi.export.c`)."""

from fdi.export.c import MAX_RING, MAX_TABLE_BYTES, PRECISIONS, CModule, generate_c, write_c

__all__ = ["MAX_RING", "MAX_TABLE_BYTES", "PRECISIONS", "CModule", "generate_c", "write_c"]
