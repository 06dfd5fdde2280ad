"""OpenEXR measurement sets and lobe tables (docs/conventions.md §6): the only module that touches files.

* :func:`write_measurements` / :func:`read_measurements` — a :class:`brdfscale.MeasurementSet`
  as one multi-part file, one part per lobe image;
* :class:`LobeTable`, :func:`write_lobe_table` / :func:`read_lobe_table` — evolved lobes at
  several scales on one half-slope grid;
* :func:`file_kind` — which of the two a file holds.

The layout (channels, attributes, checks) is documented in :mod:`brdfscale.exr._format`
and docs/synth_exr.md. Every reader validates every attribute and checksum and raises
:class:`brdfscale.MeasurementFileError` naming the file, the part and the attribute.
"""

from typing import TYPE_CHECKING

from ._format import FORMAT_VERSION
from ._measurements import file_kind, read_measurements, write_measurements


if TYPE_CHECKING:  # for static tools; at run time __getattr__ imports them on first use
    from ._tables import LobeTable, read_lobe_table, write_lobe_table


_TABLES = ("LobeTable", "read_lobe_table", "write_lobe_table")


def __getattr__(name: str):  # the lobe tables need JAX; measurement files do not (``brdfscale info`` starts fast)
    if name in _TABLES:
        from . import _tables

        value = getattr(_tables, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "write_measurements",
    "read_measurements",
    "LobeTable",
    "write_lobe_table",
    "read_lobe_table",
    "file_kind",
    "FORMAT_VERSION",
]
