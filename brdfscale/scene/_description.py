"""What a scene asks for: materials, queries (i, o, m∞, μ), and an error target.

A *material* is a lobe measured at a reference scale μ0 together with the scale law of its
facet-slope statistics; its BRDF at any scale μ is the lobe evolved by seed Eq. 4.4,

    G(W, μ) = G(W, μ0) · S(W, μ0) / S(W, μ),      ρ(i, o, m∞, μ) = A · F(i, o) · g_μ(m_s(i, o) − m∞),

with ``F`` the mirror-microfacet factor of :func:`brdfscale.geometry.microfacet_factor`
(docs/conventions.md §1–2). An *anisotropic material* (:class:`AnisotropicMaterial`) is a BRDF that
depends on the facet's whole orientation Γ ∈ SO(3) — tilt and twist — with statistics of
facet orientations that evolve on SO(3) (seed §5, docs/conventions.md §3):

    R^J(μ) = R^J(μ0) exp(−(τ(μ0) − τ(μ)) G^J),      ρ(i, o, Γ∞, μ) = Σ_J Σ_{MM'} R^J_{MM'}(μ) D^J_{MM'}(Γ∞).

A *query* is one (i, o, m∞, twist, μ, material) tuple; a :class:`Scene` is the list
of queries present plus the error target, either given explicitly or produced by a
:class:`Camera` looking at a textured plane (:func:`camera_scene`).
"""

import math
from collections.abc import Callable, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import InvalidInputError
from .._show import concrete, Shown
from .._validation import as_float_array, is_concrete, positive
from ..geometry import validate_directions
from ..lobes import AbstractLobe
from ..so3 import AnisotropicMicrofacetLobe, DiffusionLaw
from ..stats import AbstractScaleLaw, AbstractSlopeDensity


class Material(Shown, eqx.Module):
    """A lobe measured at scale ``mu0`` and the scale law of its facet-slope statistics.

    Args:
        lobe: the lobe at μ0 (:mod:`brdfscale.lobes`).
        mu0: the facet size at which ``lobe`` was measured (length units of the scene).
        law: a :mod:`brdfscale.stats` scale law (``law.at(μ)`` is ``s(·, μ)``), e.g.
            ``ScaledFamily(stats.GGX, WidthLaw(...))`` or ``GaussianSurface(...)``.
        regularisation: Tikhonov λ of the division in Eq. 4.4 (see :func:`brdfscale.evolve`).

    All array fields are differentiable parameters of a :class:`~brdfscale.scene.Plan`.
    """

    lobe: AbstractLobe
    mu0: Float[Array, ""]
    law: AbstractScaleLaw
    regularisation: Float[Array, ""]

    def __init__(self, lobe: AbstractLobe, mu0: Float[ArrayLike, ""], law: AbstractScaleLaw, regularisation=0.0):
        if not isinstance(lobe, AbstractLobe):
            raise InvalidInputError(f"lobe must be a brdfscale.lobes lobe; got {type(lobe).__name__}.")
        if not isinstance(law, AbstractScaleLaw):
            raise InvalidInputError(
                "law must be a brdfscale.stats scale law (ScaledFamily, GaussianSurface, ...); "
                f"got {type(law).__name__}."
            )
        self.lobe = lobe
        self.mu0 = positive(mu0, "mu0", "a positive facet size")
        self.law = law
        self.regularisation = as_float_array(regularisation, "regularisation")
        if is_concrete(self.regularisation) and not float(self.regularisation) >= 0:
            raise InvalidInputError(
                f"regularisation must be ≥ 0 (see brdfscale.evolve); got {float(self.regularisation)}."
            )

    def statistics(self, mu) -> AbstractSlopeDensity:
        """``s(·, μ)``."""
        return self.law.at(mu)


class AnisotropicMaterial(Shown, eqx.Module):
    """A BRDF of the facet's whole orientation Γ (tilt and twist), measured at scale ``mu0``,
    and the rotational-diffusion scale law of its facet-orientation statistics (seed §5).

    Args:
        lobe: :class:`brdfscale.so3.AnisotropicMicrofacetLobe` — ``ρ(i, o, Γ)`` of a facet with
            orientation Γ (Beckmann or GGX with roughness α_x along the facet's tangent, α_y
            along its bitangent), the BRDF at μ0.
        mu0: the facet size at which ``lobe`` was measured.
        law: :class:`brdfscale.so3.DiffusionLaw` — statistics ``S̃^J(μ) = exp(−τ(μ) G^J)``,
            ``G = D_x J_x² + D_y J_y² + D_z J_z²``, τ(μ) = α(μ)²/4.

    At a scale μ ≥ μ0 (τ(μ) ≤ τ(μ0)) the BRDF is ``R^J(μ) = R^J(μ0) exp(−(τ(μ0) − τ(μ)) G^J)``
    (:func:`brdfscale.so3.evolve_diffusion`), a function of the global orientation Γ∞ of each
    query (:class:`Queries`: its slope m∞ and twist). Finer scales (a deconvolution on SO(3))
    are not planned: use :func:`brdfscale.so3.evolve` with ``regularisation`` directly.
    All array fields are differentiable parameters of a :class:`~brdfscale.scene.Plan`.
    """

    lobe: AnisotropicMicrofacetLobe
    mu0: Float[Array, ""]
    law: DiffusionLaw

    def __init__(self, lobe: AnisotropicMicrofacetLobe, mu0: Float[ArrayLike, ""], law: DiffusionLaw):
        if not isinstance(lobe, AnisotropicMicrofacetLobe):
            raise InvalidInputError(
                f"lobe must be a brdfscale.so3.AnisotropicMicrofacetLobe; got {type(lobe).__name__} (slope-space "
                "lobes belong in brdfscale.scene.Material)."
            )
        if not isinstance(law, DiffusionLaw):
            raise InvalidInputError(
                f"law must be a brdfscale.so3.DiffusionLaw (rotational-diffusion statistics); got {type(law).__name__}."
            )
        self.lobe = lobe
        self.mu0 = positive(mu0, "mu0", "a positive facet size")
        self.law = law

    def tau(self, mu) -> Float[Array, "..."]:
        """The diffusion time ``τ(μ)`` of the statistics at scale μ."""
        return self.law.tau(mu)


class Queries(Shown, eqx.Module):
    """The (i, o, m∞, twist, μ, material) tuples a scene needs, one per row.

    ``i``, ``o``: unit directions (Q, 3) towards light and detector (z = macroscopic normal);
    ``mu``: facet size (Q,) > 0; ``m_inf``: global facet slope (Q, 2), default flat;
    ``twist``: the global frame's twist ψ about its normal (Q,) in radians, default 0 (used by
    :class:`AnisotropicMaterial` only); ``material``: index (Q,) into the scene's materials,
    default 0. The global orientation is ``Γ∞ = U(φ) A(β) U(ψ − φ)`` with β = atan|m∞| and
    φ = atan2(m∞_y, m∞_x): the minimal tilt of the normal to slope m∞, then the twist ψ
    (the convention of :class:`brdfscale.so3.TiltTwist`).
    """

    i: Float[Array, "Q 3"]
    o: Float[Array, "Q 3"]
    mu: Float[Array, " Q"]
    m_inf: Float[Array, "Q 2"]
    twist: Float[Array, " Q"]
    material: Int[Array, " Q"]

    def __init__(self, i, o, mu, m_inf=None, material=None, twist=None):
        self.i = validate_directions(jnp.atleast_2d(as_float_array(i, "i")), "i")
        self.o = validate_directions(jnp.atleast_2d(as_float_array(o, "o")), "o")
        self.mu = jnp.atleast_1d(positive(mu, "mu", "a positive facet size"))
        n = self.mu.shape[0]
        if n == 0:
            raise InvalidInputError(
                "Queries needs at least one (i, o, μ) query; got none (e.g. a camera that sees "
                "only sky: plan the pixels that see the surface)."
            )
        if self.mu.ndim != 1 or self.i.shape != (n, 3) or self.o.shape != (n, 3):
            raise InvalidInputError(
                f"i and o must have shape (Q, 3) and mu shape (Q,) with the same Q; got {self.i.shape}, "
                f"{self.o.shape}, {self.mu.shape}."
            )
        self.m_inf = jnp.zeros((n, 2), self.mu.dtype) if m_inf is None else as_float_array(m_inf, "m_inf")
        if self.m_inf.shape != (n, 2):
            raise InvalidInputError(f"m_inf must have shape ({n}, 2); got {self.m_inf.shape}.")
        self.twist = jnp.zeros(n, self.mu.dtype) if twist is None else as_float_array(twist, "twist")
        if self.twist.shape != (n,):
            raise InvalidInputError(f"twist must have shape ({n},) (radians); got {self.twist.shape}.")
        self.material = jnp.zeros(n, int) if material is None else jnp.asarray(material)
        if self.material.shape != (n,) or not jnp.issubdtype(self.material.dtype, jnp.integer):
            raise InvalidInputError(f"material must be integer indices of shape ({n},); got {self.material.shape}.")

    def __len__(self):
        return self.mu.shape[0]

    def _show_items(self) -> list[tuple[str, object]]:
        items: list[tuple[str, object]] = [("n", len(self))]
        if concrete(self.mu):
            mu = np.asarray(self.mu)
            items.append(("mu", f"{mu.min():.4g} … {mu.max():.4g}" if mu.min() < mu.max() else mu[0]))
            items.append(("materials", len(np.unique(np.asarray(self.material)))))
        return items

    def euler_angles(self) -> Float[Array, "Q 3"]:
        """z-y-z Euler angles (φ, β, ψ − φ) of each query's global orientation Γ∞."""
        phi = jnp.arctan2(self.m_inf[:, 1], self.m_inf[:, 0])
        beta = jnp.arctan(jnp.linalg.norm(self.m_inf, axis=-1))
        return jnp.stack([phi, beta, self.twist - phi], -1)


class Scene(Shown, eqx.Module):
    """Materials, the queries present, and the error target.

    ``tol`` is the error target relative to each query's lobe peak at its own scale,
    ``|ρ − ρ_exact| ≤ tol · A F max_u g_μ(u)``: the convention of :func:`brdfscale.evolve`.
    ``pixels`` / ``resolution`` (from :func:`camera_scene`) say where each query lands in an
    image; explicit query lists leave them None.
    """

    materials: tuple[Material | AnisotropicMaterial, ...]
    queries: Queries
    tol: float = eqx.field(static=True)
    pixels: Int[Array, " Q"] | None = None
    resolution: tuple[int, int] | None = eqx.field(static=True, default=None)

    def _show_items(self):
        materials = (
            self.materials[0]
            if len(self.materials) == 1
            else "; ".join(f"{type(m.lobe).__name__} lobe, {type(m.law).__name__}" for m in self.materials)
        )
        items = [("materials", materials), ("queries", len(self.queries)), ("tol", self.tol)]
        return items + ([("camera", f"{self.resolution[0]}×{self.resolution[1]} px")] if self.resolution else [])

    def __check_init__(self):
        if not self.materials or not all(isinstance(m, (Material, AnisotropicMaterial)) for m in self.materials):
            raise InvalidInputError(
                "materials must be a non-empty sequence of brdfscale.scene.Material or AnisotropicMaterial."
            )
        if not isinstance(self.queries, Queries):
            raise InvalidInputError(f"queries must be brdfscale.scene.Queries; got {type(self.queries).__name__}.")
        if not (isinstance(self.tol, float) and 0 < self.tol < 1):
            raise InvalidInputError(f"tol must be a float in (0, 1); got {self.tol!r}.")
        index = self.queries.material
        if (
            is_concrete(index)
            and len(self.queries)
            and (int(index.min()) < 0 or int(index.max()) >= len(self.materials))
        ):
            raise InvalidInputError(
                f"query material indices must lie in [0, {len(self.materials) - 1}]; "
                f"got [{int(index.min())}, {int(index.max())}]."
            )


class Camera(Shown, eqx.Module):
    """A pinhole camera at ``height`` above the plane z = 0, looking along +x, tilted down by ``pitch``.

    ``fov``: vertical (= horizontal) field of view in radians; ``resolution``: (rows, columns).
    A pixel's ray hits the plane at distance ``t``; its footprint there is a ``t δ × t δ/cos θ_o``
    patch (δ = fov/rows, θ_o the viewing angle from the normal), and the facet size the pixel
    resolves is the patch's square root of area, ``μ = t δ / √cos θ_o``. Rays that miss the
    plane (sky) produce no query.
    """

    height: float = eqx.field(static=True)
    pitch: float = eqx.field(static=True)
    fov: float = eqx.field(static=True)
    resolution: tuple[int, int] = eqx.field(static=True)

    def __check_init__(self):
        if not (self.height > 0 and 0 < self.fov < math.pi and -math.pi / 2 < self.pitch < math.pi / 2):
            raise InvalidInputError(
                f"need height > 0, 0 < fov < π and |pitch| < π/2; got {self.height}, {self.fov}, {self.pitch}."
            )
        if len(self.resolution) != 2 or min(self.resolution) < 1:
            raise InvalidInputError(f"resolution must be (rows, columns) ≥ 1; got {self.resolution!r}.")

    def rays(self) -> np.ndarray:
        """Unit ray directions (rows, columns, 3); row 0 is the top of the image."""
        rows, cols = self.resolution
        f = 0.5 / math.tan(self.fov / 2)  # focal length in units of the image height
        y = (np.arange(rows) + 0.5) / rows - 0.5  # image-down
        x = ((np.arange(cols) + 0.5) / cols - 0.5) * cols / rows
        X, Y = np.meshgrid(x, y)
        c, s = math.cos(self.pitch), math.sin(self.pitch)
        forward, up = np.array([c, 0.0, -s]), np.array([s, 0.0, c])
        right = np.array([0.0, -1.0, 0.0])
        d = f * forward + X[..., None] * right - Y[..., None] * up
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


Texture = Callable[[np.ndarray], np.ndarray]


def camera_scene(
    materials: Sequence[Material | AnisotropicMaterial],
    camera: Camera,
    light: Float[ArrayLike, "3"],
    tol: float,
    texture: Texture | None = None,
) -> Scene:
    """The queries of a camera looking at the textured plane z = 0 lit by a distant light.

    ``light``: unit direction towards the light; ``texture`` maps plane points (..., 2) to
    material indices (default: material 0 everywhere). Each pixel that sees the plane gives one
    query with ``o`` towards the camera, ``m∞ = 0`` and ``μ`` from :class:`Camera`.
    """
    light = np.asarray(validate_directions(light, "light"), dtype=float)
    d = camera.rays().reshape(-1, 3)
    hit = d[:, 2] < -1e-9
    t = camera.height / -d[hit, 2]
    points = np.array([0.0, 0.0, camera.height]) + t[:, None] * d[hit]
    o = -d[hit]
    mu = t * (camera.fov / camera.resolution[0]) / np.sqrt(o[:, 2])
    index = np.zeros(len(t), int) if texture is None else np.asarray(texture(points[:, :2]), int)
    queries = Queries(np.broadcast_to(light, o.shape), o, mu, material=index)
    return Scene(tuple(materials), queries, float(tol), jnp.asarray(np.flatnonzero(hit)), camera.resolution)
