"""Derived quantities: the model's physical quantities and the ratios ``S(W, μ0)/S(W, μ_k)``
at θ and at draws of θ — the one place every result, report, figure and sampler computes them.

* :func:`quantity_names` — the names of ``model.quantities``, in the model's order;
* :func:`quantities_at` — the quantities at a stack of θ (posterior draws, Laplace draws), name
  → array, in the model's order (one compiled ``jax.vmap``);
* :func:`ratio_frequencies`, :func:`ratio_names` — where the ratios are reported;
* :func:`evaluate`, :func:`evaluate_many` — quantities and ratios at θ̂, their Jacobians there
  and their values at the Laplace draws, for one material or a stack (what
  :mod:`fitting._analysis` summarises);
* :func:`covariance_differences`, :func:`summarise_covariance_differences` — ΔΣ(μ0, μ_k) =
  Σ(μ0) − Σ(μ_k) of any model at θ and with its Laplace standard errors;
* :func:`covariance_truth`, :func:`compare_covariance_differences` — the true ΔΣ of the surface a measurement set
  was made from, where its metadata records the surface's facet statistics, and the pulls of a fit's ΔΣ against it.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from brdfscale import InvalidInputError

from ._data import Dataset
from ._model import moments
from ._parametric import ParametricModel


__all__ = [
    "RATIO_FREQUENCIES",
    "FIXED_NOTE",
    "DIFFERENCE_COMPONENTS",
    "DIFFERENCE_ENTRIES",
    "compare_covariance_differences",
    "covariance_differences",
    "covariance_truth",
    "evaluate",
    "evaluate_many",
    "is_isotropic",
    "quantities_at",
    "quantity_names",
    "quantity_vector",
    "ratio_frequencies",
    "ratio_names",
    "summarise_covariance_differences",
]


def quantity_names(model) -> list:
    """The names of ``model.quantities``, in its order (from an abstract evaluation: no
    computation; not from ``eval_shape``'s output, a dict that comes back with sorted keys)."""
    names = []

    def capture(t):
        quantities = model.quantities(t)
        names.extend(quantities)
        return jnp.stack(list(quantities.values()))

    jax.eval_shape(capture, jax.ShapeDtypeStruct((len(model.names),), jnp.float64))
    return names


def quantity_vector(model, theta):
    """``model.quantities(θ)`` as one vector, in the order of :func:`quantity_names`."""
    return jnp.stack(list(model.quantities(theta).values()))


@eqx.filter_jit
def _quantity_draws(model, thetas):
    return jax.vmap(lambda t: quantity_vector(model, t))(thetas)


def quantities_at(model, thetas) -> dict:
    """The model's quantities at every θ of ``thetas`` (…, d): name → NumPy array (…), in the
    model's order (:func:`quantity_names`)."""
    thetas = jnp.asarray(thetas)
    flat = np.asarray(_quantity_draws(model, thetas.reshape(-1, thetas.shape[-1])))
    return {name: flat[:, i].reshape(thetas.shape[:-1]) for i, name in enumerate(quantity_names(model))}


RATIO_FREQUENCIES = (0.5, 1.0, 2.0)
"""The frequencies |W| at which the ratios ``S(W, μ0)/S(W, μ_k)`` are reported, in units of
``1/α``, α the half-maximum width of the widest (coarsest-scale) images: there every scale's
lobe transform is still well above the noise (``≈ e^{−1/16}, e^{−1/4}, e^{−1}`` of its peak for
a Beckmann lobe), so the ratio ``G(W, μ_k)/G(W, μ0)`` is what the images measure."""


def ratio_frequencies(data: Dataset) -> np.ndarray:
    """The reported ratios' frequencies |W| for this dataset (:data:`RATIO_FREQUENCIES` / α)."""
    _, width2 = moments(data)
    return np.asarray(RATIO_FREQUENCIES) / np.sqrt(max(float(np.max(width2)), 1e-300))


def ratio_names(data: Dataset, W) -> list[str]:
    """``"S(μ0)/S(μk) @ |W|=w"`` for every coarser scale k and frequency w."""
    return [f"S(μ0)/S(μ{k}) @ |W|={w:.4g}" for k in range(1, len(data.scales)) for w in np.asarray(W)]


def _evaluation(model, theta, draws, W, scales):
    """The quantities and the ratios ``S(W, μ0)/S(W, μ_k)``, k ≥ 1 (flattened), each at θ̂, their
    Jacobian there, and at every Laplace draw."""

    def quantities(t):
        return quantity_vector(model, t)

    def ratios(t):
        return model.relative_statistics(t, W, scales)[1:].ravel()

    return (
        quantities(theta),
        jax.jacfwd(quantities)(theta),
        jax.vmap(quantities)(draws),
        ratios(theta),
        jax.jacfwd(ratios)(theta),
        jax.vmap(ratios)(draws),
    )


evaluate = eqx.filter_jit(_evaluation)
"""Quantities and ratios at θ̂, their Jacobians and their values at the draws: ``(model, θ̂,
draws, W, scales) → (q, ∂q/∂θ, q(draws), r, ∂r/∂θ, r(draws))``."""

evaluate_many = eqx.filter_jit(jax.vmap(_evaluation))
""":func:`evaluate` of a stack of materials of one structure (every argument stacked)."""


def covariance_differences(model, theta, scales) -> jax.Array:
    """ΔΣ(μ0, μ_k) = Σ(μ0) − Σ(μ_k) (K, 2, 2) of ``model`` at θ (row 0 is 0), in slope units².

    ΔΣ_k is the difference of the second moments of the lobes, ``C(μ_k) − C(μ0)`` (seed Eq. 4.4:
    ``G(W, μ_k) = G(W, μ0) R_k(W)`` with ``R_k = S(μ0)/S(μ_k)``, and cumulants add), i.e.

        ΔΣ_k = −∇²_W log R_k(W) at W = 0.

    A model with a ``covariance_differences(θ, scales)`` method (:class:`fitting.AnisotropicModel`:
    exact) gives its own — and a model whose ``R_k`` depends on the direction of W must; for the
    models whose ``R_k`` is a function of |W| (``model.relative_statistics`` over radii) (``R_k`` a function of |W|) the
    Hessian is ``−(d²/dk²) log R_k(k)|₀ · I``, taken by ``jax.jacfwd`` twice of
    ``model.relative_statistics`` (tests/test_anisotropic.py checks it against the Gaussian closed
    form ``(α(μ0)² − α(μ_k)²)/2 · I`` of Beckmann statistics and the non-parametric model's
    ``2 D_k(W_1)/W_1²``). Statistics without finite second moments (GGX: ``R_k`` is not twice
    differentiable at 0; autodiff at 0 would return a finite 0) give NaN, which :func:`summarise_covariance_differences`
    reports as undetermined (None)."""
    own = getattr(model, "covariance_differences", None)
    if own is not None:
        return own(theta, scales)
    if isinstance(model, ParametricModel) and model.statistics != "beckmann":
        # GGX slopes have no finite variance (brdfscale.stats.GGX): ΔΣ is not defined; the
        # Hessian of log(xK₁(x)) at 0 diverges like log|W| (autodiff would give a finite 0)
        return jnp.full((len(scales), 2, 2), jnp.nan, dtype=jnp.result_type(theta, float))

    def log_ratio(k):
        return jnp.log(model.relative_statistics(theta, k[None], scales)[:, 0])

    curvature = jax.jacfwd(jax.jacfwd(log_ratio))(jnp.zeros((), jnp.result_type(theta, float)))
    return -curvature[:, None, None] * jnp.eye(2, dtype=curvature.dtype)


@eqx.filter_jit
def _covariance_differences_and_jacobian(model, theta, scales):
    def flat(t):
        return covariance_differences(model, t, scales)[1:].reshape(-1)

    return flat(theta), jax.jacfwd(flat)(theta)


DIFFERENCE_ENTRIES = (("xx", 0, 0), ("xy", 0, 1), ("yy", 1, 1))
"""The entries of a ΔΣ(μ0, μ_k), each ``(name, row, column)`` of its 2 × 2 matrix, in the order fit.json, the
command's tables and :func:`summarise_covariance_differences`' joint covariance give them: xx, xy, yy (public as
``fitting.DIFFERENCE_ENTRIES``, the one table of them)."""

DIFFERENCE_COMPONENTS = tuple((a, b) for _, a, b in DIFFERENCE_ENTRIES)
""":data:`DIFFERENCE_ENTRIES` without the names: the ``(row, column)`` of xx, xy, yy."""


def summarise_covariance_differences(model, theta, scales, analysis) -> tuple[list[dict], np.ndarray]:
    """ΔΣ(μ0, μ_k) for every coarser measured scale with standard errors: ``{"mu0", "mu", "value":
    [[xx, xy], [xy, yy]], "std": [[…], […]]}`` (slope units², fit.json's
    ``covariance_differences``), and their joint covariance (``FitResult.differences_covariance``):
    ``3(K − 1)`` rows and columns, per coarser scale the components :data:`DIFFERENCE_COMPONENTS` (xx, xy, yy),
    ``g Cov(θ) gᵀ`` by the same policy (:meth:`brdfscale.laplace.Laplace.covariance_of`: its diagonal is the
    squared std), NaN in the rows and columns of an entry without std.

    The standard errors propagate the Laplace covariance of θ linearly, ``Var ΔΣ_ab = g_abᵀ Cov(θ)
    g_ab`` with ``g_ab = ∂ΔΣ_ab/∂θ`` (``jax.jacfwd``), through ``analysis``
    (:class:`brdfscale.laplace.Laplace`: the determined directions' variance plus the undetermined
    ones' linearised contribution, the policy of every other quantity of a fit). An entry the
    undetermined directions move more than the determined ones, or a non-finite one, has std
    None; a non-finite value is None too.

    An isotropic model (:func:`is_isotropic`) has ``ΔΣ_xy = 0`` by construction, not by
    measurement: that entry's value is 0, its std None and ``"fixed"`` marks it (``[[False,
    True], [True, False]]``, with ``"note"`` saying why); a model that measures every entry
    gives neither key. Consumers of the std (z-scores, :func:`fitting.assess`) leave a
    fixed entry out instead of treating it as known to within 0 (tests/test_adequacy.py)."""
    scales = np.asarray(scales)
    isotropic = is_isotropic(model)
    fixed = [[False, isotropic], [isotropic, False]]
    values, jac = (np.asarray(x) for x in _covariance_differences_and_jacobian(model, jnp.asarray(theta), scales))
    finite = np.isfinite(values) & np.all(np.isfinite(jac), axis=1)
    safe = np.where(finite[:, None], jac, 0.0)
    var_d, var_u = analysis.variances(safe)
    determined = analysis.quantity_is_determined(safe) & finite
    std = np.where(determined, np.sqrt(np.maximum(var_d + var_u, 0.0)), np.nan)
    rows = np.array([4 * (k - 1) + 2 * a + b for k in range(1, len(scales)) for a, b in DIFFERENCE_COMPONENTS], int)
    is_fixed = np.array([fixed[a][b] for _ in range(1, len(scales)) for a, b in DIFFERENCE_COMPONENTS], dtype=bool)
    kept = determined[rows] & ~is_fixed
    joint = np.full((rows.size, rows.size), np.nan)
    joint[np.ix_(kept, kept)] = analysis.covariance_of(safe[rows[kept]])
    out = []
    for k in range(1, len(scales)):
        block = slice(4 * (k - 1), 4 * k)
        v, s, ok = values[block].reshape(2, 2), std[block].reshape(2, 2), finite[block].reshape(2, 2)
        out.append(
            {
                "mu0": float(scales[0]),
                "mu": float(scales[k]),
                "value": [[float(v[a, b]) if ok[a, b] else None for b in range(2)] for a in range(2)],
                "std": [
                    [float(s[a, b]) if np.isfinite(s[a, b]) and not fixed[a][b] else None for b in range(2)]
                    for a in range(2)
                ],
                **({"fixed": [list(row) for row in fixed], "note": FIXED_NOTE} if isotropic else {}),
            }
        )
    return out, joint


FIXED_NOTE = "ΔΣ_xy = 0 fixed by the isotropic model (not measured; no standard error)"
"""fit.json's ``note`` on the ΔΣ entries of an isotropic model (:func:`summarise_covariance_differences`)."""


def is_isotropic(model) -> bool:
    """True when ``model``'s ΔΣ is a multiple of the identity by construction: it has no
    ``covariance_differences`` of its own (``R_k`` a function of |W|: :func:`covariance_differences`)
    or it is built isotropic (:class:`fitting.AnisotropicModel` ``isotropic=True``,
    :class:`fitting.AnisotropicNonParametricModel` ``harmonics=0``)."""
    return (
        getattr(model, "covariance_differences", None) is None
        or bool(getattr(model, "isotropic", False))
        or getattr(model, "harmonics", None) == 0
    )


def covariance_truth(metadata, scales) -> list | None:
    """The true ΔΣ(μ0, μ_k) of the surface a measurement set was made from, for every coarser scale of ``scales``
    (the fitted scales, μ0 the first): the widening of the lobe the set's images hold, from the truth
    ``brdfscale synth`` (``--topography`` included) and the ray-traced instrument record in the metadata. A list of
    2 × 2 lists (slope²), one per coarser scale; None where the metadata records no facet statistics or not at
    every fitted scale (a file from elsewhere).

    * Where the record has ``truth.offset_covariance`` (:func:`brdfscale.synth.gonioreflectometer` with the
      ``nearly_flat`` weighting: every pixel facet counts once) it is ``O(μ_k) − O(μ0)``, O(μ) the covariance of
      the pixel slopes' offsets from their facet's slope that the image at μ holds before the micro lobe's and
      the resolution's blur (:func:`brdfscale.synth.offset_moments`): what the images determine.
    * Otherwise (the instrument; the ``projected_area`` weighting, whose images weight each pixel by its light)
      it is ``C(μ0) − C(μ_k)`` of ``truth.facet_slope_covariance``, the covariance C(μ) of the surface's μ-facet
      slopes (seed Eq. 4.4: the lobe at μ_k is the lobe at μ0 widened by ΔΣ, for Gaussian increments).

    The two agree when every scale's images come from the same pixels (the law of total variance) and differ
    where the pixel population changes with μ: a field with unmeasured pixels is measured in fewer places by a
    coarser facet, which on frt-1 of tests/data leaves out the steep pixels by the holes — between 2 and 24
    pixels the facets' ΔΣ is positive while the images narrow (tests/test_covariance_truth.py checks the truth
    against the noise-free images' own moments).

    A record that is there but damaged (not one 2 × 2 finite symmetric matrix per recorded scale) raises
    InvalidInputError naming the key — before the fit, as :func:`fitting.truth_of` does. Verified in
    ``tests/test_covariance_truth.py`` against the facet slopes of the file's field computed by hand."""
    record = metadata.get("truth") if isinstance(metadata, dict) else None
    if not isinstance(record, dict) or "facet_slope_covariance" not in record:
        return None
    offsets = "offset_covariance" in record and metadata.get("weighting", "nearly_flat") == "nearly_flat"
    key = "offset_covariance" if offsets else "facet_slope_covariance"
    at = _recorded_covariances(metadata, record, key, scales)
    if at is None:
        return None
    return [(c - at[0]).tolist() if offsets else (at[0] - c).tolist() for c in at[1:]]


def _recorded_covariances(metadata, record, key, scales) -> list | None:
    """``record[key]`` (one symmetric 2 × 2 matrix per ``metadata["scales"]``) at each of ``scales``; None when a
    fitted scale was not recorded; InvalidInputError naming ``truth.KEY`` when the record is damaged."""
    recorded = metadata.get("scales")
    try:
        covariances = np.asarray(record[key], dtype=float)
        recorded = np.asarray(recorded, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        covariances, recorded = np.zeros(0), np.zeros(0)
    if (
        covariances.ndim != 3
        or covariances.shape[1:] != (2, 2)
        or len(covariances) != len(recorded)
        or not (np.all(np.isfinite(covariances)) and np.all(np.isfinite(recorded)))
        or not np.allclose(covariances, np.swapaxes(covariances, 1, 2))
    ):
        raise InvalidInputError(
            f"metadata truth.{key} must hold one symmetric 2 × 2 covariance of finite numbers per scale of the "
            f"metadata's scales ({len(recorded)} recorded); got an array of shape {np.shape(covariances)}. Correct "
            "or remove it from the measurement set's metadata."
        )
    at = []
    for mu in np.asarray(scales, dtype=float).reshape(-1):
        match = np.flatnonzero(np.isclose(recorded, mu, rtol=1e-9, atol=0.0))
        if len(match) != 1:
            return None
        at.append(covariances[match[0]])
    return at


def compare_covariance_differences(entries: list[dict], truth: list | None) -> list[dict]:
    """``entries`` (:func:`summarise_covariance_differences`, fit.json's ``covariance_differences``) with, where
    ``truth`` (:func:`covariance_truth`) is known, each entry's ``"truth"`` (its 2 × 2 true ΔΣ) and ``"pull"``:
    ``(value − truth)/std`` per component, None where the fit gave no standard error or the model fixes the entry
    (an isotropic model's ΔΣ_xy: no pull on what was not measured). The entries are returned unchanged without
    truth, or when it does not have one matrix per entry."""
    if truth is None or len(truth) != len(entries):
        return entries
    out = []
    for d, t in zip(entries, truth):
        fixed = d.get("fixed") or [[False, False], [False, False]]
        pull = [
            [
                (d["value"][a][b] - t[a][b]) / d["std"][a][b]
                if d["value"][a][b] is not None
                and d["std"][a][b] is not None
                and d["std"][a][b] > 0
                and not fixed[a][b]
                and math.isfinite(d["std"][a][b])
                else None
                for b in range(2)
            ]
            for a in range(2)
        ]
        out.append({**d, "truth": [list(map(float, row)) for row in t], "pull": pull})
    return out
