"""The regularised plus-distributions ``h_n``: generalised functions of mass 0 on slope space
(seed §6, docs/conventions.md §4)."""

import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, Float

from .._errors import InvalidInputError, SingularDensityError
from .._slopes import add_offset, check_slopes, offset_norm, phase
from .._validation import positive, vector2
from ..stats import AbstractGeneralisedDensity
from ._action import radial_action
from ._transform import check_order, transforms_radial, transforms_scaled


_ANGLES = 64


class PlusDistribution(AbstractGeneralisedDensity):
    """The regularised 2D plus-distribution ``h_n = (1/2π) [θ(x0 − |m|) logⁿ(|m|/x0)/|m|²]₊``.

    Defined by its action on a test function ψ (docs/conventions.md §4; seed §6 without its divergence):

        ⟨h_n, ψ⟩ = ∫_0^{x0} (logⁿ(x/x0)/x) (ψ̄(x) − ψ(c)) dx,

    where ``ψ̄(x)`` is the mean of ψ over the circle of radius x about the centre ``c``
    (``mean``, default the origin). Away from ``c`` it is the function
    ``logⁿ(|m − c|/x0) / (2π |m − c|²)`` on the disk ``|m − c| < x0``; the subtraction at ``c``
    makes it integrate to **zero** against constants, so it carries no mass (``H_n(0) = 0``) and
    has no pointwise density. Its transform (:func:`plus_transform`) is

        H_n(W) = ∫_0^{x0} (logⁿ(x/x0)/x)(J₀(|W| x) − 1) dx,   times e^{−iW·c} when shifted.

    ``order`` n ∈ {0, …, 6}; ``x0`` > 0 is the cut-off slope. It is a
    :class:`brdfscale.stats.AbstractGeneralisedDensity` (mass 0, no pointwise density), not an
    :class:`~brdfscale.stats.AbstractSlopeDensity`: a physical statistic must have mass 1 and
    be non-negative, so :func:`brdfscale.evolve`, :class:`brdfscale.lobes.Lobe`,
    :class:`brdfscale.stats.Mixture` and the micro lobes of :mod:`brdfscale.synth` refuse it.
    Use it through :class:`NearlySpecular` (``a δ + Σ c_n h_n + w s_smooth``, mass 1).
    """

    order: int = eqx.field(static=True)
    x0: Float[Array, ""]
    mean: Float[Array, "2"] | None
    isotropic: bool = eqx.field(static=True)

    def __init__(self, order: int, x0: Float[ArrayLike, ""], *, mean: Float[ArrayLike, "2"] | None = None):
        self.order = check_order(order)
        self.x0 = positive(x0, "x0", "a positive cut-off slope")
        if self.x0.ndim != 0:
            raise InvalidInputError(f"x0 must be a scalar; got shape {self.x0.shape}.")
        self.mean = vector2(mean, "mean")
        self.isotropic = mean is None

    def density(self, m):
        raise SingularDensityError(
            f"the plus-distribution h_{self.order} has no pointwise density (it is a generalised "
            "function with a subtraction at its centre); use .apply(psi) for its action on a test "
            "function, .cf(W) for its transform, or observe it through an instrument "
            "(brdfscale.plus.observe) before evaluating."
        )

    def cf(self, W: Float[ArrayLike, "*batch 2"]) -> Complex[Array, "*batch"]:
        W = check_slopes(W, "W")
        H = transforms_scaled(W, self.x0, self.order)[..., self.order]
        return H * phase(W, self.mean)

    def cf_radial(self, k: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
        if self.mean is not None:
            return super().cf_radial(k)
        k = jnp.asarray(k)
        return transforms_radial(k, self.x0, self.order)[..., self.order]

    def apply(self, psi, *, scale: Float[ArrayLike, ""] | None = None, angles: int = _ANGLES) -> Float[Array, ""]:
        """``⟨h_n, ψ⟩`` for a test function ``psi`` mapping slopes (..., 2) to values (...).

        ψ̄ is the trapezoidal mean over ``angles`` directions (spectrally accurate for ψ smooth
        on circles), and the radial integral is the panelled Gauss–Legendre rule of
        ``brdfscale.plus._action`` with ``scale`` (default ``x0/10``) the shortest length on
        which ψ varies. Accuracy against mpmath is tested in tests/test_plus_distribution.py.
        """
        if not callable(psi):
            raise InvalidInputError(f"psi must be a callable taking slopes (..., 2); got {type(psi).__name__}.")
        if int(angles) != angles or angles < 4:
            raise InvalidInputError(f"angles must be an integer ≥ 4; got {angles!r}.")
        centre = jnp.zeros(2, self.x0.dtype) if self.mean is None else self.mean
        scale = self.x0 / 10 if scale is None else positive(scale, "scale")
        phi = jnp.arange(angles, dtype=self.x0.dtype) * (2 * math.pi / angles)
        ring = jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)  # (angles, 2)
        at_centre = jnp.asarray(psi(centre))

        def excess(x):
            values = jnp.asarray(psi(centre + x[..., None, None] * ring))  # (..., nodes, angles)
            return jnp.mean(values, axis=-1) - at_centre

        return radial_action(excess, self.x0, self.order, scale)[..., self.order]

    def shifted(self, offset):
        return PlusDistribution(self.order, self.x0, mean=add_offset(self.mean, offset))

    def support_radius(self, tol):
        return jnp.asarray(self.x0 + offset_norm(self.mean))

    def bandwidth(self, tol):
        # |H_n| grows like lnⁿ⁺¹(|W| x0): the transform never decays.
        return jnp.asarray(jnp.inf)
