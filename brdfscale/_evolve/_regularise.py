"""Choosing the Tikhonov λ of the evolution's division from the data (``regularisation="auto"``).

Going finer (``s_to`` wider than ``s_from``) Eq. 4.4 divides by a transform that decays faster
than the one it multiplies by: a deconvolution. The library regularises the division,
``1/S_to → S_to*/(|S_to|² + λ²)``, which is the Tikhonov solution of the consistency relation
``g_from ∗ s_from = g_to ∗ s_to`` for the unknown ``g_to``. With measured input the right λ
depends on the noise of the measurement, so it is chosen from the measurement itself.

The data are the lobe's table (``lobes.Tabulated``, or a :class:`brdfscale.lobes.Lobe` whose
shape is a :class:`brdfscale.stats.Tabulated`): node values ``v`` on an ``n_y × n_x`` grid of
spacings ``h_x, h_y``. On the table's own DFT frequencies ``W_k`` (spacing ``2π/(n h)`` per
axis, up to its Nyquist frequency ``π/h``: beyond it the table carries no data) the node sum
``V_k = h_x h_y Σ v e^{−iW_k·m}`` holds white noise when the nodes' noise is independent, and
the evolution acts on it as the linear smoother ``V ↦ f V`` with the Tikhonov filter factors

    f_k(λ) = |S_to(W_k)|² / (|S_to(W_k)|² + λ²)

(the data predicted by the evolved lobe, ``G_to S_to / S_from``, are ``f G_from``). Three rules
choose λ over candidates from 1e-10 to 10 (20 per decade, refined between the neighbours of
the best candidate):

* ``"gcv"`` — generalised cross-validation (Golub, Heath & Wahba 1979): minimise
  ``GCV(λ) = Σ_k |(1 − f_k) V_k|² / (Σ_k (1 − f_k))²``. Needs nothing but the data; the
  default (``"auto"``), chosen by the study ``experiments/stability.py`` (docs/results.md).
* ``"discrepancy"`` — Morozov's discrepancy principle: the largest λ whose residual
  ``Σ_k |(1 − f_k) V_k|²`` does not exceed the expected noise ``N h_x² h_y² Σ_nodes σ²``
  (``N`` nodes; ``noise`` σ per node or one σ for all, in the units of the table's values).
  Needs the noise level, given explicitly (``noise=``).
* ``"l_curve"`` — the corner of the L-curve (Hansen): the λ of largest curvature of
  ``(ln ‖residual‖, ln ‖G_to‖)`` on the table's frequencies.

Whatever the rule, :func:`brdfscale.evolve` then checks that the lobe exists at the λ chosen and,
where it does not, tries :data:`SEARCH_CANDIDATES` best GCV score first (:func:`ranked`,
``_flow.searched``).

Lobes that are not tabulated are exact (closed forms, analytic families): every rule gives
λ = 0, which is Eq. 4.4 itself. When nothing is divided (``s_to`` a point mass, ``|S_to| = 1``)
λ = 0 as well. Only the lobe's noise is modelled: tabulated *statistics* are taken as exact.
"""

import math

import jax.numpy as jnp
import numpy as np

from .._errors import InvalidInputError, UnresolvedMethodError
from .._validation import is_concrete
from ..stats import Delta, Tabulated


RULES = ("gcv", "discrepancy", "l_curve")
DEFAULT_RULE = "gcv"
"""The rule of ``regularisation="auto"``: in every run of the stability study (45 noisy
coarse → fine evolutions, docs/results.md) its error was within 1.2× of the best fixed λ
chosen in hindsight, where the L-curve missed by up to ×38 (disk statistics, whose transform
has zeros: the curve has no single corner) and the discrepancy principle by up to ×8e4 (the
residual stays at the noise level over decades of λ, so the crossing is ill-determined)."""
NAMES = ("auto",) + RULES
CANDIDATES = np.logspace(-10.0, 1.0, 221)
"""λ candidates (20 per decade) over which each rule is evaluated."""

_DESCRIPTION = {
    "gcv": "generalised cross-validation",
    "discrepancy": "discrepancy principle",
    "l_curve": "L-curve corner",
}


def rule_name(value) -> str | None:
    """The rule a ``regularisation`` argument names (``"auto"`` is the default rule), None for a
    number; InvalidInputError naming the accepted values for any other string."""
    if not isinstance(value, str):
        return None
    if value not in NAMES:
        raise InvalidInputError(
            f"regularisation must be a number λ ≥ 0 or one of {', '.join(repr(n) for n in NAMES)} (a rule that "
            f"chooses λ from a tabulated lobe; 'auto' is {DEFAULT_RULE!r}); got {value!r}."
        )
    return DEFAULT_RULE if value == "auto" else value


def check_noise(rule: str | None, noise):
    """``noise`` as a float array, required by the discrepancy rule and refused otherwise."""
    if noise is None:
        if rule == "discrepancy":
            raise InvalidInputError(
                "regularisation='discrepancy' needs the noise level of the lobe's table: pass noise=σ (the standard "
                "deviation of each node value, in the units of the values; one number or an array of the table's "
                "shape), or use regularisation='gcv' (or 'auto'), which needs none."
            )
        return None
    if rule != "discrepancy":
        raise InvalidInputError(
            f"noise= is used by regularisation='discrepancy' only; got it with regularisation={rule!r}"
            " (GCV and the L-curve estimate the noise from the data)."
        )
    if isinstance(noise, (str, bytes)):
        raise InvalidInputError(f"noise must be a standard deviation σ ≥ 0 (or an array of them); got {noise!r}.")
    try:
        sigma = jnp.asarray(noise, dtype=jnp.result_type(float))
    except (TypeError, ValueError):
        raise InvalidInputError(
            f"noise must be a standard deviation σ ≥ 0 (or an array of them); got {type(noise).__name__}."
        ) from None
    if is_concrete(sigma):
        s = np.asarray(sigma)
        if not (np.all(np.isfinite(s)) and np.all(s >= 0)) or not np.any(s > 0):
            raise InvalidInputError(f"noise must be finite standard deviations ≥ 0, not all 0; got {s!r}.")
    return sigma


def table_of(lobe):
    """``(values, (h_x, h_y))`` of the lobe's table (values in the lobe's units, ``A·g`` at the
    nodes), or None when the lobe is not tabulated."""
    shape = lobe.shape
    if not isinstance(shape, Tabulated):
        return None
    return shape.values * lobe.amplitude, shape.spacing


def needs_data(lobe, s_to) -> bool:
    """Whether a rule has anything to choose: a tabulated lobe and a division (structure only,
    the same under tracing)."""
    return isinstance(lobe.shape, Tabulated) and not isinstance(s_to, Delta)


def unresolved_regularisation(rule: str) -> UnresolvedMethodError:
    return UnresolvedMethodError(
        f"regularisation={rule!r} chooses λ from the tabulated lobe's values, which are traced here (inside jax.jit, "
        "grad or vmap) and so unknown. Choose it outside the transformation from concrete values, `method = "
        f"brdfscale.select(lobe, s_from, s_to, regularisation={rule!r})` (the resolved method carries λ; "
        "method.explain() reports it), and pass `method=method` inside, or pass λ as a number."
    )


def choose(lobe, s_from, s_to, rule: str, noise=None) -> tuple[float, str]:
    """``(λ, how)`` by ``rule`` for concrete inputs (module docstring); ``how`` describes the
    choice without the value (it is a static field of the method that carries λ: a new value
    must not recompile)."""
    if not isinstance(lobe.shape, Tabulated):
        return 0.0, f"{_DESCRIPTION[rule]}: the lobe is not tabulated, so it is taken as exact"
    if isinstance(s_to, Delta):
        return 0.0, f"{_DESCRIPTION[rule]}: nothing is divided, s_to is a point mass"
    if not is_concrete((lobe, s_from, s_to, noise)):
        raise unresolved_regularisation(rule)
    table = table_of(lobe)
    assert table is not None  # the lobe is tabulated (checked above)
    V2, s2, W, (hx, hy) = _spectra(table, s_to)
    ny, nx = V2.shape
    if rule == "gcv":
        lam = _gcv(V2, s2)
        detail = f"generalised cross-validation on the lobe table's {ny}×{nx} frequencies"
    elif rule == "discrepancy":
        sigma = np.asarray(noise, dtype=float)
        if sigma.ndim and sigma.shape != V2.shape:
            raise InvalidInputError(
                f"noise must be one σ or an array of the table's shape {V2.shape}; got shape {sigma.shape}."
            )
        sigma = np.broadcast_to(sigma, V2.shape)
        target = V2.size * (hx * hy) ** 2 * float(np.sum(sigma**2))
        lam = _discrepancy(V2, s2, target)
        detail = f"discrepancy principle (residual ≤ expected noise, {ny}×{nx} frequencies)"
    else:
        hat = (np.sinc(W[..., 0] * hx / (2 * np.pi)) * np.sinc(W[..., 1] * hy / (2 * np.pi))) ** 2
        F2 = np.abs(np.asarray(s_from.cf(jnp.asarray(W)))) ** 2
        lam = _l_curve(V2, s2, V2 * hat**2 * F2 * s2)
        detail = f"L-curve corner on the lobe table's {ny}×{nx} frequencies"
    return lam, detail


SEARCH_CANDIDATES = np.logspace(-10.0, 1.0, 23)
"""The λ (2 per decade) that ``regularisation="auto"`` (any rule) tries, best by GCV first, when
its rule's λ gives no lobe that exists (:func:`ranked`)."""


def ranked(lobe, s_from, s_to, rule: str, noise=None) -> list[tuple[float, str]]:
    """The λ to try in turn, each with how it was chosen: the rule's own choice (:func:`choose`),
    then :data:`SEARCH_CANDIDATES` in increasing generalised cross-validation score (the score
    needs nothing but the data). :func:`brdfscale.evolve` takes the first for which the evolved
    lobe exists (``_flow.searched``): existence is not monotone in λ on measured data (issue 31:
    λ = 0.01 exists, 0.1 does not, 1.0 does on one file)."""
    first = choose(lobe, s_from, s_to, rule, noise)
    if not needs_data(lobe, s_to):
        return [first]
    table = table_of(lobe)
    assert table is not None
    V2, s2, _, _ = _spectra(table, s_to)
    order = np.argsort(_gcv_values(V2, s2, SEARCH_CANDIDATES), kind="stable")
    rest = [
        (float(SEARCH_CANDIDATES[i]), f"{_DESCRIPTION['gcv']} score rank {r + 1} of {len(order)}")
        for r, i in enumerate(order)
    ]
    return [first] + [c for c in rest if not math.isclose(c[0], first[0], rel_tol=1e-9)]


def _spectra(table, s_to):
    """``(|V|², |S_to|², W, (h_x, h_y))``: the data's and the division's spectra on the table's own
    DFT frequencies ``W`` (n_y, n_x, 2) (module docstring), the one place every rule and the
    existence search take them from."""
    values, h = table
    v = np.asarray(values, dtype=float)
    hx, hy = (float(x) for x in np.asarray(h))
    ny, nx = v.shape
    wx = 2 * np.pi * np.fft.fftfreq(nx, hx)
    wy = 2 * np.pi * np.fft.fftfreq(ny, hy)
    W = np.stack(np.meshgrid(wx, wy), axis=-1)
    V2 = np.abs(hx * hy * np.fft.fft2(v)) ** 2
    s2 = np.abs(np.asarray(s_to.cf(jnp.asarray(W)))) ** 2
    return V2, s2, W, (hx, hy)


def _residual(V2, s2, t):
    return float(np.sum(V2 * (t / (s2 + t)) ** 2))


def _gcv_value(V2, s2, lam):
    t = lam * lam
    one_minus = t / (s2 + t)
    return float(np.sum(V2 * one_minus**2)) / float(np.sum(one_minus)) ** 2


def _gcv_values(V2, s2, lams) -> np.ndarray:
    """``GCV(λ)`` at each of ``lams``: the one scan of the GCV score, for the rule (:func:`_gcv`) and
    the existence search (:func:`ranked`)."""
    return np.array([_gcv_value(V2, s2, float(lam)) for lam in lams])


def _gcv(V2, s2) -> float:
    values = _gcv_values(V2, s2, CANDIDATES)
    best = int(np.argmin(values))
    # golden-section refinement in ln λ between the neighbours of the best candidate
    lo = math.log(CANDIDATES[max(best - 1, 0)])
    hi = math.log(CANDIDATES[min(best + 1, len(CANDIDATES) - 1)])
    f = lambda x: _gcv_value(V2, s2, math.exp(x))
    g = (math.sqrt(5) - 1) / 2
    a, b = lo + (1 - g) * (hi - lo), lo + g * (hi - lo)
    fa, fb = f(a), f(b)
    for _ in range(30):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = lo + (1 - g) * (hi - lo)
            fa = f(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = f(b)
    x = a if fa <= fb else b
    return math.exp(x) if min(fa, fb) <= values[best] else float(CANDIDATES[best])


def _discrepancy(V2, s2, target) -> float:
    residual = np.array([_residual(V2, s2, lam * lam) for lam in CANDIDATES])  # increasing in λ
    within = np.nonzero(residual <= target)[0]
    if within.size == 0:
        return float(CANDIDATES[0])
    i = int(within[-1])
    if i == len(CANDIDATES) - 1:
        return float(CANDIDATES[-1])
    lo, hi = math.log(CANDIDATES[i]), math.log(CANDIDATES[i + 1])
    for _ in range(40):  # bisection of the crossing in ln λ
        mid = 0.5 * (lo + hi)
        if _residual(V2, s2, math.exp(2 * mid)) <= target:
            lo = mid
        else:
            hi = mid
    return math.exp(lo)


def _l_curve(V2, s2, solution_weights) -> float:
    t = CANDIDATES**2
    rho = np.array([np.sum(V2 * (x / (s2 + x)) ** 2) for x in t])
    eta = np.array([np.sum(solution_weights / (s2 + x) ** 2) for x in t])
    u = np.log(CANDIDATES)
    x, y = 0.5 * np.log(np.maximum(rho, 1e-300)), 0.5 * np.log(np.maximum(eta, 1e-300))
    dx, dy = np.gradient(x, u), np.gradient(y, u)
    ddx, ddy = np.gradient(dx, u), np.gradient(dy, u)
    kappa = (dx * ddy - ddx * dy) / np.maximum(dx**2 + dy**2, 1e-300) ** 1.5
    interior = kappa[1:-1]
    return float(CANDIDATES[1 + int(np.argmax(interior))])
