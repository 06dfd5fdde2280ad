"""Masking and shadowing in the measurement-set forward model (issue 32 item 4; docs/masking.md).

A measurement set's image at scale μ and incident direction i holds the lobe ``A·g_μ(u)`` over
half-vector slope offsets ``u`` (docs/conventions.md §6; the measured ρ is that times
``F = 1/(4 cosθ_o cos⁴θ_h)``). With masking and shadowing the measured lobe is

    v(u) = G₂(i, o(u)) · A·g_μ(u),     o(u) = reflect(i, h(u)),  h(u) = (u, 1)/√(1 + |u|²),

(``G₂/E(i)`` with multiply scattered light, ``"smith_ms"``: :meth:`brdfscale.lobes.SmithMasking.albedo`),

the outgoing direction of the pixel (the mirror facet of slope u reflects i into o). G₂ is the
masking choice's (:class:`brdfscale.lobes.SmithMasking`: ``1/(1 + Λ(i) + Λ(o))``) with the lobe
at that scale as the facet-slope density — which does not depend on the incident direction
(the nearly-flat lobe, seed §2) and is taken from the data: the image of that scale nearest
normal incidence (the least masked, and the least cut by the horizon: at grazing incidence the
facets that reflect below the horizon are missing from an image), unmasked by :data:`ITERATIONS`
fixed-point steps ``G ← G₂(density of v/G)`` from ``G = 1``, its valid pixels as a
:class:`brdfscale.stats.PixelGaussians`. The factor is thus known before the fit and fixed:
:meth:`fitting.Dataset.from_measurements` divides each valid pixel's value and σ by it
(:func:`masking_factors`). The models then predict the unmasked lobe, replicate incident
directions at one scale are replicates again, and the fits' sufficient statistics
(:meth:`fitting.Dataset.points`) stay exact; a prediction times the factor is the masked forward
model.

Pixels whose outgoing direction lies on or below the horizon (o_z ≤ 0), or whose factor is
below :data:`SMALLEST_FACTOR` (a detector at grazing exitance), carry no usable light and are
masked out. Tested in tests/test_masking.py.
"""

import numpy as np

from brdfscale import geometry, lobes, stats


__all__ = ["masking_factors", "masking_factor", "unmasked_lobe", "SMALLEST_FACTOR", "ITERATIONS"]

ITERATIONS = 3
"""Fixed-point steps ``G ← G₂(density of v/G)`` from ``G = 1`` (G depends weakly on the density: the
third step changes it by < 1e-6 in tests/test_masking.py)."""

SMALLEST_FACTOR = 1e-9
"""Pixels attenuated by more than this factor are masked out (their σ/G would leave the σ range)."""


def _outgoing(incident, extent: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(i, o, leaves)`` per pixel of an ``n × n`` image over ``[−extent, extent]²``: the incident
    direction (3,), the outgoing direction ``reflect(i, h(u))`` (the normal z where it does not
    leave the surface) and whether it leaves (o_z > 0)."""
    x = np.linspace(-extent, extent, n)
    u = np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)
    h = np.asarray(geometry.slope_to_direction(u))
    i = np.asarray(incident, dtype=float)
    o = np.asarray(geometry.reflect(np.broadcast_to(i, h.shape), h))
    o = o / np.linalg.norm(o, axis=-1, keepdims=True)
    leaves = o[..., 2] > 0
    return i, np.where(leaves[..., None], o, np.array([0.0, 0.0, 1.0])), leaves


def masking_factor(masking: lobes.AbstractMasking, density, incident, extent: float, n: int) -> np.ndarray:
    """The masking choice's factor (``G₂(i, o(u))``, or ``G₂/E(i)`` with multiply scattered light:
    ``masking.factor``) with the facet-slope density ``density`` at every pixel of an ``n × n`` image
    over ``[−extent, extent]²``; 0 where no light leaves towards the pixel's detector direction or
    the factor is below :data:`SMALLEST_FACTOR`."""
    i, o, leaves = _outgoing(incident, extent, n)
    g = np.asarray(masking.factor(density, i, o))
    return np.where(leaves & (g >= SMALLEST_FACTOR), g, 0.0)


def unmasked_lobe(masking: lobes.AbstractMasking, values, valid, incident, extent: float):
    """The lobe of one image with its own masking removed, as the density of its facet slopes: the
    fixed point of ``G ← G₂(PixelGaussians(v/G))`` after :data:`ITERATIONS` steps from ``G = 1``."""
    g = np.ones(values.shape)
    density = None
    for _ in range(ITERATIONS):
        lobe = np.divide(values, g, out=np.zeros(values.shape), where=valid & (g > 0))
        density = stats.PixelGaussians(lobe, extent=extent)
        g = masking_factor(masking, density, incident, extent, values.shape[0])
    return density


def masking_factors(masking: lobes.AbstractMasking, images, values, valid) -> list[np.ndarray]:
    """The factor of every image (module docstring): ``images`` the :class:`brdfscale.LobeImage` list,
    ``values`` and ``valid`` their luminance (n, n) and valid pixels."""
    densities = {}
    factors = []
    for img in images:
        if img.mu not in densities:
            same = [k for k, other in enumerate(images) if other.mu == img.mu]
            k = max(same, key=lambda j: images[j].incident[2])  # nearest normal incidence
            ref = images[k]
            densities[img.mu] = unmasked_lobe(masking, values[k], valid[k], ref.incident, ref.extent)
        factors.append(masking_factor(masking, densities[img.mu], img.incident, img.extent, img.size))
    return factors
