"""A ray-traced multi-scale gonioreflectometer on Mitsuba 3 (issue 32; extra ``brdfscale[render]``).

* :func:`measure` — lobe images of a :class:`brdfscale.synth.HeightField` at several spot sizes μ and incident
  directions, as a :class:`brdfscale.MeasurementSet` in the layout of :func:`brdfscale.synth.gonioreflectometer`
  (half-slope offsets, ``ρ = A·g(u)/(4 cosθ_o cos⁴θ_h)``), with the Monte Carlo standard error as σ: spots aligned to
  their own mean planes, mirror/Beckmann/GGX facets with optional Fresnel, shadowing and masking by ray
  intersection, interreflection up to ``bounces``;
* :class:`Measurement` — the same measurement split into :class:`Task` s that give the same result, bit for bit,
  whatever the split, run in this process or as Ray tasks (``measure(..., workers=N)`` or ``address=``, the extra
  ``brdfscale[cluster]``, as ``fit-library`` runs a library) or on any cluster that can pickle them;
* :func:`mesh` — a height field as a Mitsuba triangle mesh, its pixel facets (default) or the continuous
  triangulation (:data:`SURFACES`, which is ``brdfscale.choices.MESHES``), unmeasured pixels left out, bounded by
  :data:`MAX_MESH_BYTES`; :func:`mesh_arrays` the same as NumPy arrays, :func:`mesh_bytes` its size.

Nothing here imports Mitsuba until called (:mod:`brdfscale._mitsuba` picks the variant). Guide: docs/instrument.md.
"""

from .._choices import BINNINGS, MESHES as SURFACES  # the names live in brdfscale.choices; kept here, public before
from ._measure import DEFAULT_BATCHES, DEFAULT_RAYS, MAX_BOUNCES, measure, Measurement, Task, TaskResult
from ._mesh import MAX_MESH_BYTES, mesh, mesh_arrays, mesh_bytes


__all__ = [
    "measure",
    "Measurement",
    "Task",
    "TaskResult",
    "mesh",
    "mesh_arrays",
    "mesh_bytes",
    "SURFACES",
    "MAX_MESH_BYTES",
    "DEFAULT_RAYS",
    "DEFAULT_BATCHES",
    "MAX_BOUNCES",
    "BINNINGS",
]
