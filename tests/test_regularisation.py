"""The automatic Tikhonov λ of evolve (``regularisation="auto"``, brdfscale._evolve._regularise):
the rules against brute-force linear algebra on the pixel grid, the auto λ against the best fixed
λ in hindsight on a noisy coarse→fine case with a closed-form truth, and its use under jax.jit."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import brdfscale as bs
from brdfscale import lobes, stats
from brdfscale._evolve import _regularise


ALPHA_LOBE, ALPHA_FINE = 0.05, 0.08
EXTENT, NODES = 0.5, 33


def _nodes():
    x = np.linspace(-EXTENT, EXTENT, NODES)
    return np.stack(np.meshgrid(x, x), axis=-1)


def _noisy_case(counts, seed=0):
    """A lobe measured at μ0 = ∞ (s_from = δ) is the fine lobe blurred by the fine statistics:
    Beckmann widths add in quadrature (closed form). Poisson counts with ``counts`` at the peak."""
    u = _nodes()
    measured = np.asarray(lobes.Beckmann(np.hypot(ALPHA_LOBE, ALPHA_FINE)).density(u))
    truth = np.asarray(lobes.Beckmann(ALPHA_LOBE).density(u))
    peak = measured.max()
    noisy = np.random.default_rng(seed).poisson(measured / peak * counts) * peak / counts
    sigma = np.sqrt(measured * peak / counts)  # the Poisson standard deviation of each node
    return lobes.Tabulated(noisy, extent=EXTENT), truth, sigma, u


METHOD = bs.Grid(size=64, extent=0.6)


def _error(lobe, lam, truth, u):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fixed grid is below what tol asks for small λ
        r = bs.evolve(
            lobe, stats.Delta(), stats.Beckmann(ALPHA_FINE), method=METHOD, regularisation=lam, check=False, tol=1e-4
        )
        return float(np.linalg.norm(np.asarray(r.density(u)) - truth) / np.linalg.norm(truth))


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@pytest.mark.parametrize("counts", [1e3, 1e5])
def test_auto_lambda_is_within_a_factor_two_of_the_best_fixed_lambda(counts):
    lobe, truth, _, u = _noisy_case(counts)
    fixed = np.logspace(-5, 0, 16)
    errors = [_error(lobe, lam, truth, u) for lam in fixed]
    best = min(errors)
    assert 1e-5 < fixed[int(np.argmin(errors))] < 1  # the best is inside the grid (a real trade-off)
    lam, _ = _regularise.choose(lobe, stats.Delta(), stats.Beckmann(ALPHA_FINE), "gcv")
    assert _error(lobe, lam, truth, u) <= 2 * best
    assert _error(lobe, 1e-8, truth, u) > 10 * best  # (nearly) unregularised, the noise explodes
    with pytest.raises(bs.InvalidInputError, match="regularisation='auto'"):
        _error(lobe, 0.0, truth, u)  # the quotient grows without bound: refused, with the fix


def _smoother(lobe, s_to, lam, extent=EXTENT):
    """The evolution's data smoother as an explicit N × N matrix on the node values:
    ``y ↦ F⁻¹ diag(f) F y`` with the 2D DFT F (a dense matrix, not the FFT) and the filter
    factors ``f = |S|²/(|S|² + λ²)`` at the table's DFT frequencies."""
    v = np.asarray(lobe.shape.values * lobe.amplitude)
    n = v.shape[0]
    h = 2 * extent / (n - 1)
    k = np.arange(n)
    dft = np.exp(-2j * np.pi * np.outer(k, k) / n)
    F = np.kron(dft, dft)  # row-major flattening of (y, x)
    w = 2 * np.pi * np.fft.fftfreq(n, h)
    W = np.stack(np.meshgrid(w, w), axis=-1).reshape(-1, 2)
    s2 = np.abs(np.asarray(s_to.cf(jnp.asarray(W)))) ** 2
    f = s2 / (s2 + lam**2)
    return np.real(np.conj(F).T @ (f[:, None] * F) / n**2), v.ravel()


def test_gcv_minimises_the_explicit_cross_validation_function():
    lobe, _, _, _ = _noisy_case(1e4)
    lobe = lobes.Tabulated(np.asarray(lobe.shape.values)[8:-8, 8:-8], extent=EXTENT / 2)  # the central 17 × 17 nodes
    s_to = stats.Beckmann(ALPHA_FINE)

    def gcv(log_lam):
        A, y = _smoother(lobe, s_to, np.exp(log_lam), EXTENT / 2)
        r = y - A @ y
        return len(y) * (r @ r) / np.trace(np.eye(len(y)) - A) ** 2

    lam, how = _regularise.choose(lobe, stats.Delta(), s_to, "gcv")
    grid = np.log(np.logspace(-6, 0, 61))
    start = grid[int(np.argmin([gcv(x) for x in grid]))]
    brute = scipy.optimize.minimize_scalar(gcv, bracket=(start - 0.1, start, start + 0.1), tol=1e-10).x
    assert abs(np.log(lam) - brute) < 1e-3
    assert "cross-validation" in how and "17×17" in how


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_discrepancy_meets_the_expected_noise_and_l_curve_finds_a_corner():
    lobe, truth, sigma, u = _noisy_case(1e4)
    s_to = stats.Beckmann(ALPHA_FINE)
    lam, _ = _regularise.choose(lobe, stats.Delta(), s_to, "discrepancy", sigma)
    A, y = _smoother(lobe, s_to, lam)
    r = y - A @ y
    # Parseval: the residual on the frequencies is N h⁴ Σ_pixels r², the noise N h⁴ Σ σ² — equal at λ
    assert r @ r == pytest.approx(np.sum(sigma**2), rel=1e-6)
    one = _regularise.choose(lobe, stats.Delta(), s_to, "discrepancy", float(np.sqrt(np.mean(sigma**2))))[0]
    assert one == pytest.approx(lam, rel=1e-6)  # one σ for all nodes: the same total noise
    corner, _ = _regularise.choose(lobe, stats.Delta(), s_to, "l_curve")
    assert 1e-5 < corner < 1 and _error(lobe, corner, truth, u) < 0.5 * _error(lobe, 1e-8, truth, u)


@pytest.mark.slow  # 15–160 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_auto_under_jit_uses_the_lambda_select_carries():
    lobe, truth, _, u = _noisy_case(1e4)
    s_from, s_to = stats.Delta(), stats.Beckmann(ALPHA_FINE)
    m = bs.select(lobe, s_from, s_to, regularisation="auto", tol=1e-4, check=False)
    lam, _ = _regularise.choose(lobe, s_from, s_to, "gcv")
    assert float(m.regularisation) == lam and m.regularisation_rule == "gcv"
    assert f"Tikhonov λ = {lam:.3g} (generalised cross-validation" in m.explain()
    eager = bs.evolve(lobe, s_from, s_to, regularisation="auto", tol=1e-4, check=False)
    assert float(eager.shape.regularisation) == lam and "Tikhonov λ" in eager.shape.discretisation.explain()
    values = lobe.shape.values * lobe.amplitude

    def density(v, reg="auto"):
        return bs.evolve(
            lobes.Tabulated(v, extent=EXTENT), s_from, s_to, method=m, regularisation=reg, tol=1e-4, check=False
        ).density(u)

    jitted = jax.jit(density)(values)
    np.testing.assert_allclose(
        np.asarray(jitted), np.asarray(eager.density(u)), rtol=1e-10, atol=1e-10 * float(jnp.max(jitted))
    )
    # the default (None) takes the method's λ too; a number given explicitly replaces it
    np.testing.assert_allclose(np.asarray(jax.jit(lambda v: density(v, None))(values)), np.asarray(jitted), rtol=1e-12)
    other = np.asarray(density(values, 10 * lam))
    assert np.max(np.abs(other - np.asarray(jitted))) > 1e-3 * float(jnp.max(jitted))
    # gradients through the carried λ: jit equals eager, and central differences
    loss = lambda v: jnp.sum(density(v) * jnp.asarray(truth))
    g_eager, g_jit = jax.grad(loss)(values), jax.jit(jax.grad(loss))(values)
    np.testing.assert_allclose(np.asarray(g_jit), np.asarray(g_eager), rtol=1e-9, atol=1e-12)
    direction = values * jnp.asarray(np.random.default_rng(1).normal(size=values.shape))  # keeps values ≥ 0
    eps = 1e-4
    numeric = (loss(values + eps * direction) - loss(values - eps * direction)) / (2 * eps)
    assert float(jnp.sum(g_eager * direction)) == pytest.approx(float(numeric), rel=1e-6)
    # without a carried λ the rule needs the values: refused with the fix
    with pytest.raises(bs.UnresolvedMethodError, match="select\\(lobe, s_from, s_to, regularisation='gcv'\\)"):
        jax.jit(
            lambda v: bs.evolve(
                lobes.Tabulated(v, extent=EXTENT),
                s_from,
                s_to,
                method=bs.Grid(size=64),
                regularisation="gcv",
                tol=1e-4,
                check=False,
            ).density(u)
        )(values)


@pytest.mark.wrong_types
def test_a_rule_name_that_is_not_one_of_the_rules_is_named():
    """evolve's regularisation is annotated with the rules' names (a Literal): a misspelled one is
    outside it; without the runtime checks the library's own message lists the rules."""
    lobe = _noisy_case(1e3)[0]
    for bad in ("gvc", "Auto", ""):
        with pytest.raises(bs.InvalidInputError, match="'auto', 'gcv', 'discrepancy', 'l_curve'"):
            bs.evolve(lobe, stats.Delta(), stats.Beckmann(0.08), regularisation=bad)


def test_exact_inputs_need_no_lambda_and_bad_arguments_are_named():
    # an analytic lobe is exact: λ = 0 by every rule, decided by structure (so also under jit)
    ggx = lobes.GGX(0.1)
    m = bs.select(ggx, stats.Beckmann(0.2), stats.Beckmann(0.1), regularisation="auto")
    assert float(m.regularisation) == 0 and "not tabulated" in m.explain()
    f = jax.jit(
        lambda a: bs.evolve(
            lobes.GGX(a), stats.Beckmann(0.2), stats.Beckmann(0.1), method=bs.Radial(nodes=512), regularisation="auto"
        ).density(jnp.zeros((1, 2)))
    )
    assert np.isfinite(float(f(0.1)[0]))
    lobe, _, sigma, _ = _noisy_case(1e3)
    assert _regularise.choose(lobe, stats.Beckmann(0.1), stats.Delta(), "gcv")[0] == 0  # nothing divided
    with pytest.raises(bs.InvalidInputError, match="needs the noise level"):
        bs.evolve(lobe, stats.Delta(), stats.Beckmann(0.08), regularisation="discrepancy")
    with pytest.raises(bs.InvalidInputError, match="used by regularisation='discrepancy' only"):
        bs.evolve(lobe, stats.Delta(), stats.Beckmann(0.08), regularisation="auto", noise=0.1)
    for noise in (-1.0, np.nan, 0.0, "x"):
        with pytest.raises(bs.InvalidInputError, match="noise must be"):
            bs.select(lobe, stats.Delta(), stats.Beckmann(0.08), regularisation="discrepancy", noise=noise)
    with pytest.raises(bs.InvalidInputError, match="table's shape"):
        _regularise.choose(lobe, stats.Delta(), stats.Beckmann(0.08), "discrepancy", sigma[:3])
    with pytest.raises(bs.InvalidInputError, match="regularisation must be ≥ 0"):
        bs.evolve(lobe, stats.Delta(), stats.Beckmann(0.08), regularisation=-1.0)


# -- issue 31, item 7: evolve on measured statistics ----------------------------------------------
def _table():
    x = np.linspace(-0.5, 0.5, 33)
    return lobes.Tabulated(np.asarray(lobes.Beckmann(0.05).density(np.stack(np.meshgrid(x, x), -1))), extent=0.5)


def test_the_existence_error_names_the_true_direction_and_the_regularisation_in_force():
    from brdfscale._existence import direction

    # the direction from the statistics themselves: Beckmann widths in closed form
    assert direction(stats.Beckmann(0.05), stats.Beckmann(0.3)) == "finer"
    assert direction(stats.Beckmann(0.3), stats.Beckmann(0.05)) == "coarser"
    assert direction(stats.GGX(0.2), stats.GGX(0.1)) == "coarser"  # heavy tails: no variance, still ordered
    assert direction(stats.Beckmann(0.1), stats.Beckmann(0.1)) == "same"
    # towards a finer scale, unregularised: a deconvolution whose transform exceeds 1
    with pytest.raises(bs.NoBRDFAtScaleError) as finer:
        bs.evolve(_table(), stats.Beckmann(0.05), stats.Beckmann(0.3), tol=1e-2)
    text = str(finer.value)
    assert text.startswith("no BRDF exists at the requested scale: the evolved lobe's transform exceeds 1")
    assert "towards a finer scale" in text and "coarser scale" not in text.split("Choose")[0]
    assert "Regularisation in force: none (λ = 0)" in text
    # towards a coarser scale with statistics that do not nest (a disk is not a Gaussian blurred):
    # the coarser diagnosis, never "a finer scale", and the λ given
    with pytest.raises(bs.NoBRDFAtScaleError) as coarser:
        bs.evolve(_table(), stats.Disk(0.2), stats.Disk(0.1), tol=1e-2, regularisation=1e-3)
    text = str(coarser.value)
    assert "towards a coarser scale" in text and "finer" not in text
    assert "Regularisation in force: Tikhonov λ = 0.001 (given)" in text


def test_ranked_candidates_start_with_the_rule_and_follow_the_gcv_score():
    lobe = _noisy_case(1e4)[0]
    s_to = stats.Beckmann(ALPHA_FINE)
    order = _regularise.ranked(lobe, stats.Delta(), s_to, "gcv")
    assert order[0] == _regularise.choose(lobe, stats.Delta(), s_to, "gcv")
    V2, s2, _, _ = _regularise._spectra(_regularise.table_of(lobe), s_to)
    scores = [_regularise._gcv_value(V2, s2, lam) for lam, _ in order[1:]]
    assert scores == sorted(scores) and len(order) == len(_regularise.SEARCH_CANDIDATES) + 1
    # an exact lobe: λ = 0 and nothing to search
    assert _regularise.ranked(lobes.GGX(0.1), stats.Delta(), s_to, "gcv")[0][0] == 0


@pytest.mark.slow  # ~15 s on 2 cores
def test_auto_finds_a_lambda_at_which_the_measured_lobe_exists():
    """docs/topography.md §3 on the AFM file mi-1 (issue 31): the GCV λ gives negative values
    going coarser; "auto" now takes the best-scoring λ for which the lobe exists, and says so."""
    from pathlib import Path

    from brdfscale import synth, topography

    field = topography.read(Path(__file__).parent / "data" / "topographies" / "mi-1.mi", detrend="curvature")
    dx = field.spacing[0]
    at0, at1 = synth.facet_statistics(field, [2 * dx, 16 * dx], bins=65, extent=1.2)
    g0 = lobes.Tabulated(at0.lobe.values, extent=1.2)
    gcv, _ = _regularise.choose(g0, at0.slopes, at1.slopes, "gcv")
    with pytest.raises(bs.NoBRDFAtScaleError, match="towards a coarser scale.*Tikhonov λ = "):
        bs.evolve(g0, at0.slopes, at1.slopes, regularisation=gcv, tol=1e-3)  # the rule's own λ: refused
    evolved = bs.evolve(g0, at0.slopes, at1.slopes, regularisation="auto", tol=1e-3)
    lam = float(evolved.shape.regularisation)
    assert lam != pytest.approx(gcv) and lam in [pytest.approx(c) for c in _regularise.SEARCH_CANDIDATES]
    explained = evolved.shape.discretisation.explain()
    assert f"Tikhonov λ = {lam:.3g}" in explained and "the rule's own λ" in explained and "refused" in explained
    x = np.linspace(-1.2, 1.2, 65)
    values = np.asarray(evolved.density(np.stack(np.meshgrid(x, x), -1)))
    assert (
        evolved.shape.tol == 1e-3 and values.min() >= -1e-3 * values.max()
    )  # it exists: no value below −tol of the peak


@pytest.mark.slow  # ~10 s on 2 cores
def test_a_relaxed_tol_is_warned_and_stated():
    with pytest.warns(bs.ToleranceRelaxedWarning, match="tol=1e-09 was asked"):
        m = bs.select(lobes.GGX(0.1), stats.Beckmann(0.1), stats.Beckmann(0.05), method="grid", tol=1e-9)
    assert m.tol > 1e-9 and f"honours tol = {m.tol:.3g} of the peak (tol = 1e-09 was asked" in m.explain()
