"""OpenEXR measurement sets and lobe tables (DESIGN §6): the only module that touches files.

* :func:`write_measurements` / :func:`read_measurements` — a :class:`brdfscale.MeasurementSet`
  as one multi-part file, one part per lobe image;
* :class:`LobeTable`, :func:`write_lobe_table` / :func:`read_lobe_table` — evolved lobes at
  several scales on one half-slope grid;
* :func:`file_kind` — which of the two a file holds.

The layout (channels, attributes, checks) is documented in :mod:`brdfscale.exr._format`
and docs/synth_exr.md. Every reader validates every attribute and checksum and raises
:class:`brdfscale.MeasurementFileError` naming the file, the part and the attribute.
"""

from ._format import FORMAT_VERSION
from ._measurements import file_kind, read_measurements, write_measurements
from ._tables import LobeTable, read_lobe_table, write_lobe_table

__all__ = [
    "write_measurements",
    "read_measurements",
    "LobeTable",
    "write_lobe_table",
    "read_lobe_table",
    "file_kind",
    "FORMAT_VERSION",
]
