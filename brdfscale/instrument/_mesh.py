"""A height field as a triangle mesh for Mitsuba 3: two triangles per pixel quad, unmeasured pixels left out.

Lengths are in pixel units of x (``Δx = 1``; ``Δy/Δx`` and the heights divided by ``Δx``), so float32 keeps the same
relative precision whatever the field's unit; slopes are ratios of lengths and do not change. Node ``(j, k)`` (row j,
column k) is the vertex ``(k, j·Δy/Δx, h[j, k]/Δx)``. The quad of nodes ``(j, k)`` … ``(j + 1, k + 1)`` is split into

* triangle A = ``(j, k), (j, k+1), (j+1, k)`` — exactly :mod:`brdfscale.synth`'s *pixel facet* (its normal slope is the
  forward difference, ``m = −∇h``), and
* triangle B = ``(j, k+1), (j+1, k+1), (j+1, k)``,

both wound so that their geometric normals point up (+z). A triangle with an unmeasured node (``field.mask`` False) is
not in the mesh, so no ray can hit it (tests/test_instrument.py::test_masked_pixels_are_never_hit).

A periodic field is meshed with a periodic margin of ``pad`` pixels on every side (the heights wrapped), so that spots
near its edges are shadowed and masked by the surface beyond them; a measured field is meshed as it is (no
margin: beyond its edges there is no surface).

Memory: the mesh's buffers take :func:`mesh_bytes` = ``12·V + 12·F`` bytes (V float32 vertex triples, F uint32 index
triples); a mesh above :data:`MAX_MESH_BYTES` is refused before anything is allocated. A 2048² field without margin
needs 4.2 M vertices and 8.4 M triangles, 151 MB (tests/test_instrument.py::test_mesh_memory_bound).
"""

from __future__ import annotations

import math

import numpy as np

from .._errors import InvalidInputError
from .._validation import integer
from ..synth import HeightField


MAX_MESH_BYTES = 2**29
"""The largest mesh the instrument builds, in bytes of vertex and index buffers (512 MiB: a 2048² field with a
periodic margin of up to 2 × 1024 pixels more per axis, 26 M triangles at most). Mitsuba's acceleration structure
comes on top (a small multiple of the buffers)."""


def _nodes(field: HeightField, pad: int) -> tuple[int, int]:
    """Nodes per axis of the meshed grid, ``(rows, cols)``."""
    ny, nx = field.shape
    if field.periodic:
        return ny + 1 + 2 * pad, nx + 1 + 2 * pad
    return ny, nx


def mesh_bytes(field: HeightField, pad: int = 0) -> int:
    """The bytes of the vertex and index buffers of :func:`mesh` for ``field`` with margin ``pad`` (an upper bound
    with a mask: every node is a vertex, every quad two triangles)."""
    rows, cols = _nodes(field, pad)
    return 12 * rows * cols + 12 * 2 * (rows - 1) * (cols - 1)


def check_pad(field: HeightField, pad) -> int:
    """``pad`` as a margin in pixels: an integer ≥ 0, 0 for a measured field, at most the field's size."""
    pad = integer(pad, "pad", 0)
    if not field.periodic and pad:
        raise InvalidInputError(
            f"pad={pad}: a measured (non-periodic) field has no surface beyond its edges to add; use pad=0."
        )
    if pad > max(field.shape):
        raise InvalidInputError(f"pad must be at most the field's size, {max(field.shape)} pixels; got {pad}.")
    return pad


def check_mesh_size(field: HeightField, pad: int) -> None:
    size = mesh_bytes(field, pad)
    if size > MAX_MESH_BYTES:
        rows, cols = _nodes(field, pad)
        raise InvalidInputError(
            f"the mesh of this {field.shape[0]} × {field.shape[1]} field (margin {pad} px) would take "
            f"{size / 2**20:.4g} MiB of buffers ({rows * cols} vertices, {2 * (rows - 1) * (cols - 1)} triangles), "
            "above "
            f"brdfscale.instrument.MAX_MESH_BYTES = {MAX_MESH_BYTES} bytes; use a smaller margin or a smaller field "
            "(a part of its heights, or brdfscale.topography.resample onto coarser pixels)."
        )


def mesh_arrays(field: HeightField, pad: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh as NumPy arrays: vertices ``(V, 3)`` float32 (pixel units), faces ``(F, 3)`` uint32 and, per face,
    the pixel quad it lies on ``(F, 2)`` int64 ``(row, col)`` in the field's own indices (wrapped for the margin)."""
    if not isinstance(field, HeightField):
        raise InvalidInputError(
            f"field must be a brdfscale.synth.HeightField (brdfscale.topography.read or from_array make one of a "
            f"measured surface); got {type(field).__name__}."
        )
    pad = check_pad(field, pad)
    check_mesh_size(field, pad)
    ny, nx = field.shape
    dx, dy = field.spacing
    rows, cols = _nodes(field, pad)
    j = np.arange(rows) - (pad if field.periodic else 0)
    k = np.arange(cols) - (pad if field.periodic else 0)
    jw, kw = j % ny, k % nx
    heights = field.heights[np.ix_(jw, kw)] - float(
        np.mean(field.heights if field.mask is None else field.heights[field.mask])
    )
    x, y = np.meshgrid(k.astype(np.float64), j * (dy / dx), indexing="xy")
    vertices = np.stack((x, y, heights / dx), axis=-1).reshape(-1, 3).astype(np.float32)
    q = (np.arange(rows - 1)[:, None] * cols + np.arange(cols - 1)[None, :]).ravel()
    v00, v01, v10, v11 = q, q + 1, q + cols, q + cols + 1
    faces = np.concatenate((np.stack((v00, v01, v10), -1), np.stack((v01, v11, v10), -1)))
    qj = np.repeat(jw[:-1], cols - 1)
    qk = np.tile(kw[:-1], rows - 1)
    quads = np.concatenate((np.stack((qj, qk), -1),) * 2)
    if field.mask is not None:
        measured = field.mask[np.ix_(jw, kw)].ravel()
        keep = measured[faces].all(axis=1)
        faces, quads = faces[keep], quads[keep]
    return vertices, faces.astype(np.uint32), quads


def mesh(field: HeightField, *, pad: int = 0, variant: str | None = None):
    """The height field as a Mitsuba 3 triangle mesh (``mi.Mesh``, face normals only, no BSDF of its own).

    Geometry and conventions: module docstring (pixel units of x, two triangles per quad, unmeasured pixels left
    out, a periodic margin of ``pad`` pixels). Mitsuba comes from :func:`brdfscale._mitsuba.mitsuba` (``variant``:
    the default picks the first that runs here). Put it in a scene with ``mi.load_dict({"type": "scene", "surface":
    mesh(field)})``. The render helpers reuse it.

    Raises:
        InvalidInputError: ``field`` not a HeightField, ``pad`` not an integer ≥ 0 (0 for a measured field), a mesh
            above :data:`MAX_MESH_BYTES`, an unknown variant.
        MissingDependencyError: Mitsuba is not installed or the variant cannot run here.
    """
    from .. import _mitsuba

    vertices, faces, _ = mesh_arrays(field, pad)
    mi = _mitsuba.mitsuba(variant)
    if len(faces) == 0:
        raise InvalidInputError("the field has no measured pixel quad to mesh.")
    shape = mi.Mesh("heightfield", len(vertices), len(faces), has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(shape)
    params["vertex_positions"] = mi.Float(vertices.ravel())
    params["faces"] = mi.UInt32(faces.ravel())
    params.update()
    return shape


def default_pad(field: HeightField, grazing_deg: float = 5.0) -> int:
    """The periodic margin the instrument uses: the horizontal distance, in pixels, over which a ray 5° above the
    horizon falls through the field's height range, plus one, capped by the field's size and :data:`MAX_MESH_BYTES`
    (0 for a measured field)."""
    if not field.periodic:
        return 0
    h = field.heights
    relief = float(h.max() - h.min()) / field.spacing[0]
    pad = min(math.ceil(relief / math.tan(math.radians(grazing_deg))) + 1, max(field.shape))
    while pad > 0 and mesh_bytes(field, pad) > MAX_MESH_BYTES:
        pad //= 2
    return pad
