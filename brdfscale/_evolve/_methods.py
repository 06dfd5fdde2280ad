"""The evolution operator's paths as objects (the pattern of lineax's ``AutoLinearSolver``).

A *method* says how :func:`brdfscale.evolve` inverts the evolved transform
``G_to = G_from S_from / S_to`` (seed Eq. 4.4):

* :class:`ClosedForm` — Gaussian/δ/mixture algebra: exact, nothing to discretise;
* :class:`Radial` — radially symmetric inputs: ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(kr) k dk`` by an
  n-node Gauss–Legendre rule on [0, K], evaluated at the queries or on a verified table of
  radii read off by cubic interpolation;
* :class:`Grid` — general inputs: ``G`` on an N × N real-FFT frequency grid over the slope
  half-width a, inverted at the queries (direct sums) or onto a finer slope grid (zero-padded
  inverse FFT) read off by bicubic interpolation;
* :class:`Auto` — the first of these that applies (:meth:`Auto.select_method`).

A method whose discretisation is not given is *unresolved*. :func:`brdfscale.select` resolves
one from concrete parameter values (nodes, cut-off, grid side and extent, interpolation
tables — each verified against the tolerance it reports); :func:`brdfscale.evolve` calls it
itself when the values are concrete. Under ``jax.jit``/``grad``/``vmap`` the values are traced
and unknown, so an unresolved spectral method is refused (:class:`UnresolvedMethodError`)
instead of falling back to a default size: resolve outside the transformation and pass the
resolved object in. A method with an explicit ``nodes`` (radial) or ``size`` (grid) but no
cut-off or extent is resolved at run time from the traced values themselves (the cut-off by
the spectral probe, the extent from the support radius): sizes are static, values are not.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._blocks import DEFAULT_BUDGET
from .._errors import InvalidInputError
from .._show import Shown
from .._validation import integer, is_concrete, real


def _optional_array(x):
    """Floats of a method as array leaves (a changed value recompiles nothing)."""
    if x is None:
        return None
    try:
        return jnp.asarray(x, dtype=jnp.result_type(float))
    except TypeError:
        raise InvalidInputError(f"expected a real number; got {type(x).__name__}.") from None


def _number(x) -> float | None:
    return None if x is None or not is_concrete(x) else float(x)


class AbstractMethod(Shown, eqx.Module):
    """How :func:`brdfscale.evolve` evaluates the evolved lobe (module docstring)."""

    _show_hidden = ("budget", "sign_check", "regularisation_note")

    @property
    def path(self) -> str:
        return type(self).__name__.lower().replace("closedform", "closed_form")

    @property
    def resolved(self) -> bool:
        """Whether every discretisation choice is fixed (no value-dependent choice left)."""
        return True

    def explain(self) -> str:
        return self.path


class ClosedForm(AbstractMethod):
    """Gaussian/δ/mixture algebra (exact); :class:`brdfscale.MethodNotApplicableError` where the
    families have no closed form."""

    def explain(self) -> str:
        return "closed form (Gaussian/δ/mixture algebra): exact"


class RadialTable(Shown, eqx.Module):
    """The radial path's table: the lobe at radii ``r_j = c sinh((j − 3) h)`` (three mirror
    nodes below r = 0, where g is even, and five beyond the last radius served), as
    ``kernel[:, j] = J₀(k_i r_j)`` on the method's Gauss–Legendre frequencies ``k_i``, read
    off by ``points``-point Lagrange interpolation in ``t = asinh(r/c)``. Uniform in r near 0
    (spacing ``c h``), geometric beyond ``c``: heavy tails need few radii."""

    # the floats are array leaves, not static fields: a new value must not recompile the evaluation
    kernel: Float[Array, "nodes radii"]
    scale: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # c
    step: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # h
    radius: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # the last radius served; beyond it g < tol/2 of its peak
    error: Float[Array, ""] = eqx.field(converter=jnp.asarray)  # verified interpolation error, relative to the peak
    points: int = eqx.field(static=True, default=8)

    @property
    def count(self) -> int:
        return self.kernel.shape[1]


class Radial(AbstractMethod):
    """The radial (Hankel) path: ``g(r) = (2π)⁻¹ ∫_0^K G(k) J₀(kr) k dk``.

    Args:
        nodes: Gauss–Legendre nodes on [0, K]; ``None`` for :func:`brdfscale.select` to choose.
        cutoff: the frequency cut-off K; ``None``: chosen at run time from the transform's
            probe (truncation below ``tol/2`` of the peak; traced values allowed).
        table: a verified table of radii (built by :func:`brdfscale.select`); ``None``:
            evaluate at the queries themselves.
        tol: the error, relative to the lobe's peak, the discretisation honours (set by
            :func:`brdfscale.select`).
        budget: bytes of temporaries an evaluation may hold at once (default 256 MiB): queries
            are evaluated in blocks that fit it, so any number of offsets can be asked for.
    """

    nodes: int | None = eqx.field(static=True, default=None)
    cutoff: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    table: RadialTable | None = None
    tol: float | None = eqx.field(static=True, default=None)
    budget: int = eqx.field(static=True, default=DEFAULT_BUDGET)
    sign_check: bool = eqx.field(static=True, default=True)
    """Whether evaluations refuse values below −tol of the peak (off where a caller's explicit
    nodes are too few for tol: their ringing is no evidence about existence)."""
    regularisation: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    """The Tikhonov λ chosen with the discretisation (:func:`brdfscale.select` with a rule or a
    λ; ``evolve(..., method=m)`` uses it unless given another); None: none chosen."""
    regularisation_rule: str | None = eqx.field(static=True, default=None)
    """How it was chosen (``"gcv"``, ``"discrepancy"``, ``"l_curve"``; ``"given"`` for a number)."""
    regularisation_note: str | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        _check_budget(self.budget)
        _check_count("Radial(nodes=...)", self.nodes, 8)
        _check_positive("Radial(cutoff=...)", self.cutoff, "a positive frequency")

    @property
    def resolved(self) -> bool:
        return self.nodes is not None

    def explain(self) -> str:
        if self.nodes is None:
            return "radial (Hankel) path, not yet resolved"
        cut = "K from the run-time probe" if self.cutoff is None else f"K = {_number(self.cutoff):.4g}"
        if self.table is None:
            layout = "evaluated at the query radii"
        else:
            t = self.table
            layout = (f"table of {t.count} radii to r = {_number(t.radius):.3g} (uniform in asinh(r/{_number(t.scale):.3g}), "
                      f"{t.points}-point Lagrange; verified error {_number(t.error):.2g} of the peak), direct at the queries "
                      "when they are few")
        tol = "" if self.tol is None else f"; honours tol = {self.tol:.3g} of the peak"
        return f"radial (Hankel) path: {self.nodes} Gauss–Legendre nodes, {cut}; {layout}{tol}{_lambda_note(self)}"


class Grid(AbstractMethod):
    """The 2D-FFT grid path: ``G`` on a ``size × size`` real-FFT frequency grid for the slope
    half-width ``extent``.

    Args:
        size: grid side (even); ``None`` for :func:`brdfscale.select` to choose.
        extent: slope half-width a of the grid; ``None``: the radius beyond which the lobe stays
            below ``tol/2`` of its peak (computed from the values, traced ones included).
            Offsets outside ``[−a, a)²`` evaluate to 0 (within tol when a is that radius;
            never a periodic image).
        oversample: the factor p of the zero-padded inverse FFT onto a slope grid of spacing
            ``h/p`` that 6 × 6-point Lagrange interpolation reads (set by
            :func:`brdfscale.select` after verifying it); ``None``: evaluate at the queries by
            direct sums.
        tol: the error the discretisation honours (set by :func:`brdfscale.select`; may be
            looser than asked when the size cap forbids the target, see ``evolve``).
        budget: bytes of temporaries an evaluation may hold at once (default 256 MiB).
    """

    size: int | None = eqx.field(static=True, default=None)
    extent: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    oversample: int | None = eqx.field(static=True, default=None)
    tol: float | None = eqx.field(static=True, default=None)
    error: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)  # verified interpolation error
    budget: int = eqx.field(static=True, default=DEFAULT_BUDGET)
    sign_check: bool = eqx.field(static=True, default=True)
    """Whether evaluations refuse values below −tol of the peak (off where a caller's explicit
    size or extent is too small for tol: its ringing and aliasing are no evidence about existence)."""
    regularisation: Float[Array, ""] | None = eqx.field(default=None, converter=_optional_array)
    """The Tikhonov λ chosen with the discretisation (as :class:`Radial`'s)."""
    regularisation_rule: str | None = eqx.field(static=True, default=None)
    regularisation_note: str | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        _check_budget(self.budget)
        _check_count("Grid(size=...)", self.size, 8)
        _check_positive("Grid(extent=...)", self.extent, "a positive slope half-width")
        _check_count("Grid(oversample=...)", self.oversample, 1)

    @property
    def resolved(self) -> bool:
        return self.size is not None

    def explain(self) -> str:
        if self.size is None:
            return "grid (2D FFT) path, not yet resolved"
        a = "a from the support radius at run time" if self.extent is None else f"half-width a = {_number(self.extent):.4g}"
        if self.oversample is None:
            layout = "inverse DFT summed at the queries"
        else:
            verified = "not verified" if self.error is None else f"verified error {_number(self.error):.2g} of the peak"
            layout = (f"zero-padded inverse FFT onto {self.size * self.oversample}² slope nodes, 6×6-point Lagrange "
                      f"({verified}), direct at the queries when they are few")
        tol = "" if self.tol is None else f"; honours tol = {self.tol:.3g} of the peak"
        return f"grid (2D FFT) path: {self.size}×{self.size} frequencies, {a}; {layout}{tol}{_lambda_note(self)}"


def _lambda_note(method) -> str:
    if method.regularisation is None:
        return ""
    value = _number(method.regularisation)
    text = "traced" if value is None else f"{value:.3g}"
    detail = "" if method.regularisation_note is None else f" ({method.regularisation_note})"
    return f"; Tikhonov λ = {text}{detail}"


def carrying(method, lam, rule: str | None, note: str | None):
    """``method`` (Radial or Grid) carrying the Tikhonov λ chosen with it (None: none)."""
    import dataclasses

    if not isinstance(method, (Radial, Grid)):
        return method
    return dataclasses.replace(method, regularisation=lam, regularisation_rule=rule, regularisation_note=note)


def carried(method):
    """``(λ, rule)`` a method carries, ``(None, None)`` when none."""
    return getattr(method, "regularisation", None), getattr(method, "regularisation_rule", None)


def _check_count(name, value, least):
    if value is not None:
        integer(value, name, least)


def _check_positive(name, value, what):
    if value is not None and is_concrete(value):
        v = np.asarray(value)
        real(v.item() if v.ndim == 0 else v, f"{name} ({what})", minimum=0.0, strict=True)


def _check_budget(budget):
    integer(budget, "budget (bytes of temporaries)", 2**20)


class Auto(AbstractMethod):
    """The first path that applies: closed form, else radial (everything radially symmetric),
    else grid (:meth:`select_method`)."""

    def select_method(self, lobe, s_from, s_to) -> AbstractMethod:
        """The path for these inputs, unresolved (structure only: the families and their
        isotropy, never parameter values, so it is the same under ``jax.jit``)."""
        from ._algebra import has_closed_form

        if has_closed_form(lobe.shape, s_from, s_to):
            return ClosedForm()
        if lobe.shape.isotropic and s_from.isotropic and s_to.isotropic:
            return Radial()
        return Grid()

    def explain(self) -> str:
        return "auto: closed form, else radial, else grid"


_NAMES = {"auto": Auto, "closed_form": ClosedForm, "radial": Radial, "grid": Grid}


def as_method(method, size=None, extent=None) -> AbstractMethod:
    """A method object from a method or its name (``size``/``extent``: the string API's
    explicit discretisation, applied to whichever spectral path is taken)."""
    if isinstance(method, AbstractMethod):
        if size is not None or extent is not None:
            raise InvalidInputError("size= and extent= go with a method name; with a method object put them in it: "
                                    "Radial(nodes=...) or Grid(size=..., extent=...).")
        return method
    if not isinstance(method, str) or method not in _NAMES:
        raise InvalidInputError(
            f"method must be 'auto', 'closed_form', 'radial' or 'grid', or a method object (brdfscale.Auto(), "
            f"ClosedForm(), Radial(...), Grid(...)); got {method!r}.")
    return _NAMES[method]()


def with_sizes(method: AbstractMethod, size, extent) -> AbstractMethod:
    """The string API's ``size=``/``extent=`` put into the path taken."""
    if size is not None:
        integer(size, "size", 8)
    if isinstance(method, Radial) and size is not None:
        return Radial(nodes=int(size))
    if isinstance(method, Grid):
        if extent is not None:
            try:
                extent = float(extent)
            except TypeError:
                raise InvalidInputError("extent must be a concrete positive number (a discretisation choice), "
                                        f"not a traced value; got {type(extent).__name__}.") from None
            if not (np.isfinite(extent) and extent > 0):
                raise InvalidInputError(f"extent must be a positive slope half-width; got {extent}.")
        return Grid(size=None if size is None else int(size), extent=extent)
    return method
