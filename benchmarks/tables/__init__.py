"""RESULTS.md's generated tables, one module per family of tables.

Each family module defines the functions that build its tables' cells from the result
records and a ``TABLES`` dict naming each table (its name in RESULTS.md's markers) with its
result files and builder; :data:`TABLES` here is all of them. :mod:`.common` holds what the
families share: the cell formats, the row look-ups and :class:`~.common.Table`.
"""

from __future__ import annotations

from . import (
    auto,
    contact,
    deploy,
    engines,
    export,
    facade,
    main_command,
    rough,
    scaling,
    soak,
    tabular,
    throughput,
    training,
)
from .common import ReportError, Table

FAMILIES = (
    engines,
    training,
    auto,
    main_command,
    tabular,
    scaling,
    facade,
    throughput,
    soak,
    export,
    deploy,
    contact,
    rough,
)


def _every_table() -> dict[str, Table]:
    """The families' tables in one dict; a name two families define is an error."""
    out: dict[str, Table] = {}
    for family in FAMILIES:
        for name, spec in family.TABLES.items():
            if name in out:
                raise ReportError(f"table {name!r} is defined twice ({family.__name__})")
            out[name] = spec
    return out


#: every generated table: its name in the markers, its result files, its generator
TABLES = _every_table()

__all__ = ["TABLES", "ReportError", "Table"]
