"""A height field as a triangle mesh for Mitsuba 3, in one of two surfaces (:data:`brdfscale.choices.MESHES`);
unmeasured pixels left out.

Lengths are in pixel units of x (``Δx = 1``; ``Δy/Δx`` and the heights divided by ``Δx``, less their mean), so
float32 keeps the same relative precision whatever the field's unit; slopes are ratios of lengths and do not change.
Node ``(j, k)`` (row j, column k) is the vertex ``(k − nx/2, (j − ny/2)·Δy/Δx, h[j, k]/Δx)`` (centred:
:func:`centre`). The *pixel facet* of quad ``(j, k)`` is
the plane through nodes ``00 = (j, k)``, ``01 = (j, k+1)`` and ``10 = (j+1, k)`` — the facet of
:class:`brdfscale.synth.HeightField`, whose normal slope is the forward difference ``m = −∇h``
(docs/conventions.md §1). The surfaces:

* ``"pixel_facets"`` (default) — the library's own surface model, the one :mod:`brdfscale.synth` takes statistics
  of: each pixel facet over its whole pixel (triangles ``00, 01, 10`` and ``01, P, 10`` with the fourth corner
  ``P = 01 + 10 − 00``), joined to its right and lower neighbours by vertical slivers ``01, 11, P`` and ``10, P, 11``
  that close the gap ``h₁₁ − P_z`` (the mixed second difference; slivers of height 0 are left out). Watertight; the
  slivers' area relative to the pixel's is about ``|∂²h/∂x∂y|·Δ``, small on a field sampled finer than its
  correlation length. 4 triangles and one extra vertex per quad.
* ``"triangles"`` — the continuous piecewise-linear surface through the nodes: triangle A = ``00, 01, 10`` (the pixel
  facet) and triangle B = ``01, 11, 10``, whose slope is not a pixel facet's (its x slope is the forward difference
  of row j+1, its y slope that of column k+1). 2 triangles per quad.

Every triangle is wound so that its normal points to the open side (up for the facets; for a sliver towards the
lower of the two facets it joins). A triangle with an unmeasured node (``field.mask`` False) is not in the mesh, so
no ray can hit it (tests/test_instrument.py::test_masked_pixels_are_never_hit).

A periodic field is meshed with a periodic margin of ``pad`` pixels on every side (the heights wrapped), so that spots
near its edges are shadowed and masked by the surface beyond them; a measured field is meshed as it is (no
margin: beyond its edges there is no surface).

Memory: the mesh's buffers take :func:`mesh_bytes` = ``12·V + 12·F`` bytes (V float32 vertex triples, F uint32 index
triples); a mesh above :data:`MAX_MESH_BYTES` is refused before anything is allocated. A 2048² measured field needs
8.4 M vertices and 16.8 M triangles as pixel facets (302 MB), 4.2 M and 8.4 M as triangles (151 MB)
(tests/test_instrument.py::test_mesh_memory_bound).
"""

from __future__ import annotations

import math

import numpy as np

from .._choices import MESHES
from .._errors import InvalidInputError
from .._validation import integer
from ..synth import HeightField


MAX_MESH_BYTES = 2**29
"""The largest mesh the instrument builds, in bytes of vertex and index buffers (512 MiB: a 2048² field as pixel
facets with a periodic margin of up to 300 pixels per side, 22 M triangles). Mitsuba's acceleration structure comes on
top (a small multiple of the buffers)."""


def _nodes(field: HeightField, pad: int) -> tuple[int, int]:
    """Nodes per axis of the meshed grid, ``(rows, cols)``."""
    ny, nx = field.shape
    if field.periodic:
        return ny + 1 + 2 * pad, nx + 1 + 2 * pad
    return ny, nx


def mesh_counts(field: HeightField, surface: str = MESHES.default, pad: int = 0) -> tuple[int, int]:
    """``(vertices, triangles)`` of :func:`mesh` at most (every quad measured, no sliver degenerate)."""
    rows, cols = _nodes(field, pad)
    quads = (rows - 1) * (cols - 1)
    if MESHES.check(surface) == "triangles":
        return rows * cols, 2 * quads
    return rows * cols + quads, 4 * quads


def mesh_bytes(field: HeightField, surface: str = MESHES.default, pad: int = 0) -> int:
    """The bytes of the vertex and index buffers of :func:`mesh` for ``field`` (``12·V + 12·F``: float32 vertex
    triples, uint32 index triples; an upper bound with a mask or flat quads)."""
    vertices, triangles = mesh_counts(field, surface, pad)
    return 12 * vertices + 12 * triangles


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


def check_mesh_size(field: HeightField, surface: str, pad: int) -> None:
    """Refuse a mesh above :data:`MAX_MESH_BYTES` before anything is allocated."""
    size = mesh_bytes(field, surface, pad)
    if size > MAX_MESH_BYTES:
        vertices, triangles = mesh_counts(field, surface, pad)
        raise InvalidInputError(
            f"the {surface} mesh of this {field.shape[0]} × {field.shape[1]} field (margin {pad} px) would take "
            f"{size / 2**20:.4g} MiB of buffers ({vertices} vertices, {triangles} triangles), above "
            f"brdfscale.instrument.MAX_MESH_BYTES = {MAX_MESH_BYTES} bytes; use a smaller margin or a smaller field "
            "(a part of its heights, or brdfscale.topography.resample onto coarser pixels)."
        )


def centre(field: HeightField) -> tuple[float, float]:
    """Where node ``(0, 0)`` would lie were the field's centre the origin, negated: the mesh's x, y are
    ``(k − nx/2, (j − ny/2)·Δy/Δx)`` — centred, because Mitsuba offsets a reflected ray's origin by
    ``(1 + max|p|)·8.9e-5`` (its float32 ``RayEpsilon``), which grows with the coordinates."""
    ny, nx = field.shape
    return nx / 2, ny / 2 * field.spacing[1] / field.spacing[0]


def check_field(field) -> HeightField:
    if not isinstance(field, HeightField):
        raise InvalidInputError(
            f"field must be a brdfscale.synth.HeightField (brdfscale.topography.read or from_array make one of a "
            f"measured surface); got {type(field).__name__}."
        )
    return field


def mesh_arrays(
    field: HeightField, surface: str = MESHES.default, pad: int = 0, *, quads: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The mesh as NumPy arrays: vertices ``(V, 3)`` float32 (pixel units), faces ``(F, 3)`` uint32 and, per face,
    the pixel quad it belongs to ``(F, 2)`` int64 ``(row, col)`` in the field's own indices (wrapped in the margin;
    None with ``quads=False``). Built in uint32 and float32 throughout: peak memory about three times the buffers."""
    check_field(field)
    surface = MESHES.check(surface)
    pad = check_pad(field, pad)
    check_mesh_size(field, surface, pad)
    ny, nx = field.shape
    dx, dy = field.spacing
    rows, cols = _nodes(field, pad)
    shift = pad if field.periodic else 0
    jw, kw = (np.arange(rows) - shift) % ny, (np.arange(cols) - shift) % nx
    level = float(np.mean(field.heights if field.mask is None else field.heights[field.mask]))
    z = (field.heights[np.ix_(jw, kw)] - level) / dx  # float64 (rows, cols)
    cx, cy = centre(field)
    x = (np.arange(cols) - shift - cx).astype(np.float32)
    y = ((np.arange(rows) - shift) * (dy / dx) - cy).astype(np.float32)
    extra = (rows - 1) * (cols - 1) if surface == "pixel_facets" else 0
    vertices = np.empty((rows * cols + extra, 3), np.float32)
    grid = vertices[: rows * cols].reshape(rows, cols, 3)
    grid[..., 0], grid[..., 1], grid[..., 2] = x[None, :], y[:, None], z
    q = (np.arange(rows - 1, dtype=np.uint32)[:, None] * cols + np.arange(cols - 1, dtype=np.uint32)[None, :]).ravel()
    v00, v01, v10, v11 = q, q + 1, q + cols, q + cols + 1
    measured = None if field.mask is None else field.mask[np.ix_(jw, kw)].ravel()
    if surface == "triangles":
        pieces = [np.stack((v00, v01, v10), -1), np.stack((v01, v11, v10), -1)]
        keeps = [None, None] if measured is None else [measured[f].all(axis=1) for f in pieces]
    else:
        # pixel facets: the quad's plane through nodes 00, 01, 10; its fourth corner P = 01 + 10 − 00
        corner = vertices[rows * cols :].reshape(rows - 1, cols - 1, 3)
        corner[..., 0], corner[..., 1] = x[None, 1:], y[1:, None]
        pz = z[:-1, 1:] + z[1:, :-1] - z[:-1, :-1]
        corner[..., 2] = pz
        wall = (z[1:, 1:] - pz != 0).ravel()  # the mixed difference: node 11 is not on the facet's plane
        present = np.ones((rows - 1, cols - 1), bool)
        if measured is not None:
            m = measured.reshape(rows, cols)
            present = m[:-1, :-1] & m[:-1, 1:] & m[1:, :-1]
        right = np.zeros_like(present)
        right[:, :-1] = present[:, :-1] & present[:, 1:]
        below = np.zeros_like(present)
        below[:-1] = present[:-1] & present[1:]
        p = np.uint32(rows * cols) + np.arange(len(q), dtype=np.uint32)
        pieces = [
            np.stack((v00, v01, v10), -1),
            np.stack((v01, p, v10), -1),
            np.stack((v01, v11, p), -1),  # x = k + 1: faces −x where node 11 lies above P
            np.stack((v10, p, v11), -1),  # y = j + 1: faces −y where node 11 lies above P
        ]
        keeps = [present.ravel(), present.ravel(), right.ravel() & wall, below.ravel() & wall]
    faces = np.concatenate([f if keep is None else f[keep] for f, keep in zip(pieces, keeps)])
    if not quads:
        return vertices, faces, None
    index = np.arange(len(q))
    which = np.concatenate([index if keep is None else index[keep] for keep in keeps])
    found = np.stack((jw[:-1][which // (cols - 1)], kw[:-1][which % (cols - 1)]), axis=-1)
    return vertices, faces, found


def mesh(field: HeightField, *, surface: str = MESHES.default, pad: int = 0, variant: str | None = None):
    """The height field as a Mitsuba 3 triangle mesh (``mi.Mesh``, face normals only, no BSDF of its own).

    Geometry and conventions: module docstring (pixel units of x; ``surface`` ``"pixel_facets"`` or
    ``"triangles"``; unmeasured pixels left out; a periodic margin of ``pad`` pixels). Mitsuba comes from
    :func:`brdfscale._mitsuba.mitsuba` (``variant``: the default picks the first that runs here). Put it in a scene
    with ``mi.load_dict({"type": "scene", "surface": mesh(field)})``. :func:`mesh_arrays` gives the same mesh as
    NumPy arrays.

    Raises:
        InvalidInputError: ``field`` not a HeightField, an unknown ``surface``, ``pad`` not an integer ≥ 0 (0 for a
            measured field), a mesh above :data:`MAX_MESH_BYTES`, an unknown variant.
        MissingDependencyError: Mitsuba is not installed or the variant cannot run here.
    """
    from .. import _mitsuba

    vertices, faces, _ = mesh_arrays(field, surface, pad, quads=False)
    mi = _mitsuba.mitsuba(variant)
    if len(faces) == 0:
        raise InvalidInputError("the field has no measured pixel quad to mesh.")
    shape = mi.Mesh("heightfield", len(vertices), len(faces), has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(shape)
    # the buffers' own array types: mi.Float / mi.UInt32 in a JIT variant, Dr.Jit's dynamic arrays in a scalar one
    params["vertex_positions"] = type(params["vertex_positions"])(vertices.ravel())
    params["faces"] = type(params["faces"])(faces.ravel())
    params.update()
    return shape


def default_pad(field: HeightField, surface: str = MESHES.default, grazing_deg: float = 5.0) -> int:
    """The periodic margin the instrument uses: the horizontal distance, in pixels, over which a ray 5° above the
    horizon falls through the field's height range, plus one, capped by the field's size and :data:`MAX_MESH_BYTES`
    (0 for a measured field)."""
    if not field.periodic:
        return 0
    h = field.heights
    relief = float(h.max() - h.min()) / field.spacing[0]
    pad = min(math.ceil(relief / math.tan(math.radians(grazing_deg))) + 1, max(field.shape))
    while pad > 0 and mesh_bytes(field, surface, pad) > MAX_MESH_BYTES:
        pad //= 2
    return pad
