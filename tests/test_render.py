"""brdfscale.render: the Mitsuba BSDF against brdfscale's own lobes, its sampling, the footprint, the engine export.

References nobody here wrote into the plugin: the lobe tables evaluated by :class:`brdfscale.lobes.Tabulated` (the
tent sum the plugin interpolates) and masked by :class:`brdfscale.lobes.SmithMasking` on the evolved shapes; a χ²
test of sampled slopes against the tabulated density; Euler's identity for a function linear in the table (the
gradient); the pinhole and orthographic footprints in closed form; OpenImageIO reading the export.
"""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.stats

import brdfscale
from brdfscale import _mitsuba, lobes, render, stats


pytest.importorskip("mitsuba")

LAW = stats.ScaledFamily(stats.Beckmann, stats.WidthLaw(0.3, 1.0, 1.0))
MU0 = 1.0
LADDER = [1.0, 3.0, 9.0]


def base_lobe():
    """Anisotropic, correlated and off-centre: a Gaussian lobe (evolved in closed form by the Beckmann law)."""
    return lobes.Lobe(stats.Gaussian(cov=[[0.006, 0.002], [0.002, 0.012]], mean=[0.04, -0.03]))


def llvm():
    problem = _mitsuba.available("llvm_ad_rgb")
    if problem:
        pytest.skip(problem)
    return _mitsuba.mitsuba("llvm_ad_rgb")


@pytest.fixture(scope="module")
def tables():
    """The lobe table of the test material (JAX, once) and its evolved lobes (brdfscale.evolve, independently)."""
    mi = llvm()
    table = render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=LADDER, size=48)
    evolved = [brdfscale.evolve(base_lobe(), LAW.at(MU0), LAW.at(mu)) for mu in LADDER]
    return mi, table, evolved


@pytest.fixture(scope="module")
def material(tables):
    """The LLVM BSDF without masking (footprint-driven μ), and its references."""
    mi, table, evolved = tables
    return mi, render.bsdf(None, table, masking=False, variant="llvm_ad_rgb"), table, evolved


@pytest.fixture(scope="module")
def masked(tables):
    """The LLVM BSDF with Smith masking (its G₁ tables cost a JAX compilation: slow tests only)."""
    mi, table, evolved = tables
    obj = render.bsdf(base_lobe(), LAW, mu0=MU0, scales=LADDER, size=48, variant="llvm_ad_rgb", form="table")
    return mi, obj, table, evolved


# -- reference values (brdfscale's lobes) ------------------------------------------------------------------------


def weights(table, mu):
    """Linear-in-ln μ weights of the ladder's scales (clamped to its ends)."""
    x = np.log(table.scales)
    t = np.clip(np.log(mu), x[0], x[-1])
    k = min(int(np.searchsorted(x, t, side="right")) - 1, len(x) - 2)
    w = np.zeros(len(x))
    f = (t - x[k]) / (x[k + 1] - x[k])
    w[k], w[k + 1] = 1 - f, f
    return w


def reference_rho(table, evolved, mu, i, o, masking=True):
    """ρ(i, o) at scale μ: the tabulated lobes (lobes.Tabulated) mixed in ln μ, times G₂ from the mixed G₁ of the
    evolved shapes (lobes.SmithMasking) — the plugin's definition, from the library's own functions."""
    w = weights(table, mu)
    rho = sum(wk * np.asarray(lobes.Tabulated(v, extent=table.extent).evaluate(i, o)) for wk, v in zip(w, table.values))
    if not masking:
        return rho
    smith = lobes.SmithMasking()
    gi = sum(wk * np.asarray(smith.g1(lobe.shape, i)) for wk, lobe in zip(w, evolved))
    go = sum(wk * np.asarray(smith.g1(lobe.shape, o)) for wk, lobe in zip(w, evolved))
    return rho * gi * go / (gi + go - gi * go)


def reference_pdf(table, mu, wi, wo):
    """Solid-angle density of the sampled wo: p_m(m_s)/(4 cos³θ_h wi·h), p_m the normalised tabulated shapes
    mixed in ln μ (stats.Tabulated normalises)."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    m = h[:, :2] / h[:, 2:]
    p = sum(
        wk * np.asarray(stats.Tabulated(v, extent=table.extent).density(m))
        for wk, v in zip(weights(table, mu), table.values)
    )
    return p / (4 * h[:, 2] ** 3 * np.sum(wi * h, axis=-1))


def directions_near_lobe(rng, n, table_centre=(0.04, -0.03), spread=0.2):
    """Detector directions o (cosθ > 0.3) and light directions i reflected about half vectors near the lobe."""
    o = rng.normal(size=(4 * n, 3))
    o[:, 2] = np.abs(o[:, 2])
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    m = np.asarray(table_centre) + spread * rng.normal(size=(4 * n, 2))
    h = np.concatenate([m, np.ones((4 * n, 1))], axis=1)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    i = 2 * np.sum(o * h, axis=1, keepdims=True) * h - o
    keep = (o[:, 2] > 0.3) & (i[:, 2] > 0.05)
    return i[keep][:n], o[keep][:n]


def interactions(mi, wi, footprint):
    """Surface interactions with wi (camera side) and a footprint of length ``footprint`` (uv partials)."""
    import drjit as dr

    n = len(wi)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[np.ascontiguousarray(wi[:, k]) for k in range(3)])
    si.dp_du = mi.Vector3f(1.0, 0.0, 0.0)
    si.dp_dv = mi.Vector3f(0.0, 1.0, 0.0)
    si.duv_dx = mi.Vector2f(np.full(n, footprint), 0.0)
    si.duv_dy = mi.Vector2f(0.0, np.full(n, footprint))
    return si


def vec(mi, a):
    return mi.Vector3f(*[np.ascontiguousarray(a[:, k]) for k in range(3)])


# -- eval and pdf against the lobes ------------------------------------------------------------------------------


@pytest.mark.slow
def test_eval_matches_the_masked_lobe_at_random_directions_and_scales(masked):
    mi, obj, table, evolved = masked
    rng = np.random.default_rng(0)
    ctx = mi.BSDFContext()
    for mu in (1.0, 2.2, 5.0, 9.0):
        i, o = directions_near_lobe(rng, 400)
        got = np.asarray(obj.eval(ctx, interactions(mi, o, mu), vec(mi, i))[0])
        ref = reference_rho(table, evolved, mu, i, o)
        big = ref > 1e-3 * ref.max()
        # the masking is read from G₁ tables on a direction grid (√cosθ, φ): linear interpolation between nodes
        assert np.max(np.abs(got[big] - ref[big]) / ref[big]) < 1e-2, mu
        assert np.median(np.abs(got[big] - ref[big]) / ref[big]) < 1e-3, mu
        assert np.all(np.abs(got[~big]) <= 2e-3 * ref.max())


def test_eval_without_masking_is_the_tabulated_lobe_to_float32(material):
    mi, obj, table, evolved = material
    rng = np.random.default_rng(1)
    ctx = mi.BSDFContext()
    for mu in (1.0, 1.7, 4.0, 9.0):
        i, o = directions_near_lobe(rng, 400)
        got = np.asarray(obj.eval(ctx, interactions(mi, o, mu), vec(mi, i))[0])
        ref = reference_rho(table, evolved, mu, i, o, masking=False)
        big = ref > 1e-3 * ref.max()
        assert np.max(np.abs(got[big] - ref[big]) / ref[big]) < 1e-4, mu  # the issue's target: 1e-4 relative


def eval_error_against_the_evolved_lobe(mi, obj, mus, rng, n=400, masking=False):
    """The largest relative error of the BSDF's eval against ``brdfscale.evolve(base, LAW.at(μ0), LAW.at(μ))``
    evaluated by :meth:`brdfscale.lobes.AbstractLobe.evaluate` (the exactly evolved lobe, not the tables), at each
    μ of ``mus``, where the lobe exceeds 1e-3 of its largest value."""
    smith = lobes.SmithMasking() if masking else lobes.NoMasking()
    worst = []
    for mu in mus:
        lobe = brdfscale.evolve(base_lobe(), LAW.at(MU0), LAW.at(float(mu)))
        i, o = directions_near_lobe(rng, n)
        got = np.asarray(obj.eval(mi.BSDFContext(), interactions(mi, o, float(mu)), vec(mi, i))[0])
        ref = np.asarray(lobe.evaluate(i, o, masking=smith))
        big = ref > 1e-3 * ref.max()
        worst.append(float(np.max(np.abs(got[big] / ref[big] - 1))))
    return np.array(worst)


# refined ladders and grids (render.bsdf(tolerance=…)): [1, 4] to 2e-2 (25 scales, 257² nodes, ~3 s) in the default
# suite, [1, 9] to 1e-2 (40 scales, 513² nodes) in the slow one; the bound is the tolerance asked for
FAST = dict(scales=[1.0, 4.0], size=65, tolerance=2e-2, form="table")
DENSE = dict(scales=[1.0, 9.0], size=65, tolerance=1e-2, form="table")


@pytest.mark.slow  # 10 s on 2 cores: the default suite measured 372 s in a clean clone at fc7a33e (budget 360)
def test_a_refined_ladder_holds_eval_within_its_tolerance_between_the_nodes(tables):
    mi = tables[0]
    obj = render.bsdf(base_lobe(), LAW, mu0=MU0, masking=False, variant="llvm_ad_rgb", **FAST)
    ladder = np.exp(obj.host.log_mu)
    np.testing.assert_allclose(ladder[[0, -1]], [1.0, 4.0], rtol=1e-12)
    assert np.all(np.diff(ladder) > 0)
    steps = np.diff(np.log(ladder))
    assert steps[0] < steps[-1] / 4  # finest near μ0, where the lobe widens fastest
    rng = np.random.default_rng(4)
    mus = [math.sqrt(ladder[0] * ladder[1]), *np.exp(rng.uniform(0.0, math.log(4.0), 2))]
    assert np.all(eval_error_against_the_evolved_lobe(mi, obj, mus, rng) < FAST["tolerance"])
    # the unrefined two-scale ladder is a mixture of its ends at √4 = 2: far off (the refinement is what holds it)
    coarse = render.bsdf(
        base_lobe(), LAW, mu0=MU0, masking=False, variant="llvm_ad_rgb", scales=[1.0, 4.0], size=65, form="table"
    )
    assert eval_error_against_the_evolved_lobe(mi, coarse, [2.0], rng)[0] > 10 * FAST["tolerance"]


@pytest.mark.slow
def test_a_refined_ladder_holds_eval_within_its_tolerance_at_dense_random_scales(tables):
    mi = tables[0]
    obj = render.bsdf(base_lobe(), LAW, mu0=MU0, variant="llvm_ad_rgb", **DENSE)  # with Smith masking
    rng = np.random.default_rng(5)
    mus = np.exp(rng.uniform(0.0, math.log(9.0), 24))
    errors = eval_error_against_the_evolved_lobe(mi, obj, mus, rng, masking=True)
    # the G₁ tables' direction interpolation (≤ 1 %, docs/render.md "Masking tables") adds to the tables' error
    assert np.all(errors < 2 * DENSE["tolerance"]), errors
    unmasked = render.bsdf(base_lobe(), LAW, mu0=MU0, masking=False, variant="llvm_ad_rgb", **DENSE)
    assert np.all(eval_error_against_the_evolved_lobe(mi, unmasked, mus, rng) < DENSE["tolerance"])


# -- the closed form (Gaussian lobes with Gaussian statistics) ---------------------------------------------------

MEASURED = stats.MeasuredScaleLaw(
    np.array([1.0, 2.0, 4.0, 8.0]),
    np.array(
        [
            [[0.03, 0.004], [0.004, 0.02]],
            [[0.02, 0.003], [0.003, 0.014]],
            [[0.011, 0.0], [0.0, 0.01]],
            [[0.004, -0.001], [-0.001, 0.005]],
        ]
    ),
)  # a measured law: Σ(μ) linear in ln μ between its scales, so the closed form's interpolation is exact


@pytest.fixture(scope="module")
def closed(tables):
    """The closed-form BSDF of base_lobe() with the measured law (default ladder: its scales are on it), masked."""
    mi = tables[0]
    return mi, render.bsdf(base_lobe(), MEASURED, mu0=MU0, levels=3, variant="llvm_ad_rgb")


def relative_errors(mi, obj, law, mu, rng, masking, n=400):
    """|eval/ρ − 1| and |pdf/p − 1| against brdfscale.evolve(base, law.at(μ0), law.at(μ)): ρ by
    AbstractLobe.evaluate with ``masking``, p the evolved shape's density in solid angle, where ρ > 1e-3 of its max."""
    lobe = brdfscale.evolve(base_lobe(), law.at(MU0), law.at(float(mu)))
    i, o = directions_near_lobe(rng, n)
    si = interactions(mi, o, float(mu))
    got = np.asarray(obj.eval(mi.BSDFContext(), si, vec(mi, i))[0])
    ref = np.asarray(lobe.evaluate(i, o, masking=masking))
    h = (i + o) / np.linalg.norm(i + o, axis=1, keepdims=True)
    p = np.asarray(obj.pdf(mi.BSDFContext(), si, vec(mi, i)))
    p_ref = np.asarray(lobe.shape.density(h[:, :2] / h[:, 2:])) / (4 * h[:, 2] ** 3 * np.sum(o * h, axis=1))
    big = ref > 1e-3 * ref.max()
    return np.abs(got[big] / ref[big] - 1), np.abs(p[big] / p_ref[big] - 1)


def test_the_closed_form_is_the_evolved_masked_lobe_to_float32_at_any_scale(closed):
    """Gaussian lobe, Gaussian statistics: eval and pdf equal the exactly evolved lobe with Smith masking (closed forms,
    brdfscale.lobes.SmithMasking) within 1e-4 — the issue's target — at the law's scales and between them."""
    mi, obj = closed
    assert obj.host.form == "closed"
    assert set(np.asarray(MEASURED.mu).tolist()) <= set(
        np.round(np.exp(obj.host.log_mu), 12).tolist()
    )  # the law's own scales are on the ladder
    rng = np.random.default_rng(11)
    for mu in (1.0, 2.0, 8.0, *np.exp(rng.uniform(0.0, math.log(8.0), 3))):
        rho, pdf = relative_errors(mi, obj, MEASURED, mu, rng, lobes.SmithMasking())
        assert rho.max() < 1e-4 and pdf.max() < 1e-4, (mu, rho.max(), pdf.max())
    separable = render.bsdf(
        base_lobe(), MEASURED, mu0=MU0, levels=3, variant="llvm_ad_rgb", masking=lobes.SmithMasking(correlated=False)
    )
    rho, _ = relative_errors(mi, separable, MEASURED, 3.0, rng, lobes.SmithMasking(correlated=False))
    assert rho.max() < 1e-4
    unmasked = render.bsdf(base_lobe(), MEASURED, mu0=MU0, levels=3, variant="llvm_ad_rgb", masking=False)
    rho, _ = relative_errors(mi, unmasked, MEASURED, 3.0, rng, lobes.NoMasking())
    assert rho.max() < 1e-4


def test_a_refined_closed_ladder_holds_its_tolerance_for_a_parametric_law(tables):
    """LAW's covariance is not linear in ln μ: the closed-form ladder is bisected until the Gaussian of the mean
    parameters is within the tolerance at every midpoint; eval then holds it at random scales."""
    mi = tables[0]
    obj = render.bsdf(
        base_lobe(), LAW, mu0=MU0, scales=[1.0, 4.0], tolerance=1e-3, masking=False, variant="llvm_ad_rgb"
    )
    assert obj.host.form == "closed" and len(obj.host.log_mu) > 2
    rng = np.random.default_rng(12)
    for mu in np.exp(rng.uniform(0.0, math.log(4.0), 3)):
        rho, _ = relative_errors(mi, obj, LAW, mu, rng, lobes.NoMasking())
        assert rho.max() < 1e-3, mu


def test_closed_form_sampling_follows_the_gaussian_chi2(closed):
    """χ² of the sampled half-vector slopes against the evolved Gaussian integrated over the bins (scipy's bivariate
    normal CDF), between two of the law's scales."""
    mi, obj = closed
    mu, n = 3.0, 40000
    shape = brdfscale.evolve(base_lobe(), MEASURED.at(MU0), MEASURED.at(mu)).shape
    rng = np.random.default_rng(13)
    wi = np.tile([[0.3, -0.2, math.sqrt(1 - 0.13)]], (n, 1))
    bs, weight = obj.sample(
        mi.BSDFContext(), interactions(mi, wi, mu), mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
    )
    wo = np.stack([np.asarray(c) for c in (bs.wo.x, bs.wo.y, bs.wo.z)], axis=1)
    m = (wi + wo)[:, :2] / (wi + wo)[:, 2:]
    edges = np.linspace(-0.6, 0.6, 13)
    counts, _, _ = np.histogram2d(m[:, 0], m[:, 1], bins=[edges, edges])
    dist = scipy.stats.multivariate_normal(np.asarray(shape.mean), np.asarray(shape.cov))
    cdf = np.array([[dist.cdf([a, b]) for b in edges] for a in edges])
    prob = cdf[1:, 1:] - cdf[:-1, 1:] - cdf[1:, :-1] + cdf[:-1, :-1]
    expected = n * prob
    use = expected > 5
    chi2 = np.sum((counts[use] - expected[use]) ** 2 / expected[use])
    outside = n - counts[use].sum(), n * (1 - prob[use].sum())
    chi2 += (outside[0] - outside[1]) ** 2 / max(outside[1], 1.0)
    assert scipy.stats.chi2.sf(chi2, int(use.sum())) > 1e-3, chi2
    check_reciprocity(mi, obj)


def test_gradients_reach_the_closed_forms_parameters(closed):
    """eval is linear in the amplitudes A_k (entries 6k of "parameters"): Σ_k A_k ∂eval/∂A_k = eval (Euler); the
    covariances receive gradients too."""
    import drjit as dr

    mi = closed[0]
    obj = render.bsdf(base_lobe(), MEASURED, mu0=MU0, levels=3, variant="llvm_ad_rgb")  # its own: traverse changes it
    params = mi.traverse(obj)
    dr.enable_grad(params["parameters"])
    params.update()
    rng = np.random.default_rng(14)
    i, o = directions_near_lobe(rng, 50)
    total = dr.sum(obj.eval(mi.BSDFContext(), interactions(mi, o, 3.0), vec(mi, i))[0])
    dr.backward(total)
    grad = np.asarray(dr.grad(params["parameters"])).reshape(-1, 6)
    values = np.asarray(params["parameters"]).reshape(-1, 6)
    np.testing.assert_allclose(np.dot(grad[:, 0], values[:, 0]), float(np.asarray(total).ravel()[0]), rtol=1e-4)
    assert np.count_nonzero(grad[:, 3:]) > 0


def test_masking_shapes_of_a_lobe_table_are_one_per_scale(material):
    """A LobeTable with masking_shapes: G₂ from the shapes given (Gaussians: closed-form Λ), one per table scale."""
    mi, _, table, evolved = material
    with pytest.raises(brdfscale.InvalidInputError, match="one slope density per scale of the LobeTable"):
        render.bsdf(None, table, masking_shapes=[stats.Gaussian(sigma=0.1)], variant="llvm_ad_rgb")
    obj = render.bsdf(None, table, masking_shapes=[lobe.shape for lobe in evolved], mu=3.0, variant="llvm_ad_rgb")
    i, o = directions_near_lobe(np.random.default_rng(15), 200)
    got = np.asarray(obj.eval(mi.BSDFContext(), interactions(mi, o, 3.0), vec(mi, i))[0])
    ref = reference_rho(table, evolved, 3.0, i, o)
    big = ref > 1e-3 * ref.max()
    assert np.median(np.abs(got[big] / ref[big] - 1)) < 1e-3  # the G₁ tables' direction interpolation (≤ 1 %)
    assert np.max(np.abs(got[big] / ref[big] - 1)) < 1e-2


def test_the_form_is_checked():
    with pytest.raises(brdfscale.InvalidInputError, match="form must be one of 'auto', 'table', 'closed'"):
        render.bsdf(base_lobe(), LAW, mu0=MU0, scales=[1.0], form="cubic")
    with pytest.raises(brdfscale.InvalidInputError, match="form='closed' needs Gaussian evolved lobes"):
        mixture = lobes.Lobe(stats.Mixture([0.5, 0.5], [stats.Gaussian(sigma=0.05), stats.Gaussian(sigma=0.1)]))
        render.bsdf(mixture, LAW, mu0=MU0, scales=[1.0], form="closed")  # evolves in closed form: to a mixture
    with pytest.raises(brdfscale.InvalidInputError, match="masking_shapes is for tabulated lobes"):
        render.bsdf(base_lobe(), LAW, mu0=MU0, scales=[1.0], form="closed", masking_shapes=[stats.Gaussian(sigma=0.1)])


def test_the_ladder_refinement_refuses_bad_tolerances(monkeypatch):
    from brdfscale.render import _material

    with pytest.raises(brdfscale.InvalidInputError, match="tolerance must be"):
        render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=[1.0, 9.0], tolerance=-1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="masking_shapes needs scales="):
        render.bsdf(base_lobe(), LAW, mu0=MU0, masking_shapes=[stats.Gaussian(cov=np.eye(2) * 0.01)])
    monkeypatch.setattr(_material, "MAX_LEVELS", 4)
    with pytest.raises(brdfscale.InvalidInputError, match="needs more than 4 scales"):
        render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=[1.0, 9.0], size=8, tolerance=1e-9)
    monkeypatch.setattr(_material, "MAX_NODES", 16)
    with pytest.raises(brdfscale.InvalidInputError, match="needs more than 16 slope nodes"):
        render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=[1.0], size=8, tolerance=1e-9)


@pytest.mark.slow
def test_masking_shapes_make_the_masking_tables(tables):
    """masking_shapes replace the evolved shapes in G₂: eval is the tabulated lobe times G₂ of the shapes given."""
    mi, table, evolved = tables
    wider = [stats.Gaussian(cov=8 * np.asarray(lobe.shape.cov)) for lobe in evolved]
    obj = render.bsdf(base_lobe(), LAW, mu0=MU0, scales=LADDER, size=48, variant="llvm_ad_rgb", masking_shapes=wider)
    rng = np.random.default_rng(6)
    for mu in (1.0, 3.0):
        i, o = directions_near_lobe(rng, 400)
        got = np.asarray(obj.eval(mi.BSDFContext(), interactions(mi, o, mu), vec(mi, i))[0])
        ref = reference_rho(table, [lobes.Lobe(w) for w in wider], mu, i, o)
        own = reference_rho(table, evolved, mu, i, o)
        big = ref > 1e-3 * ref.max()
        assert np.median(np.abs(got[big] / ref[big] - 1)) < 1e-3, mu
        assert np.max(np.abs(got[big] / own[big] - 1)) > 5e-2, mu  # the wider shapes do change the masking


@pytest.mark.slow
def test_masking_at_the_nodes_of_its_direction_grid_is_smiths(masked):
    """Directions on the G₁ grid's nodes: no interpolation in direction, so G₂ equals SmithMasking's to float32."""
    mi, obj, table, evolved = masked
    nodes = render._masking.directions()[1:].reshape(-1, 3)
    rng = np.random.default_rng(2)
    i = nodes[rng.choice(len(nodes), 300)]
    o = nodes[rng.choice(len(nodes), 300)]
    keep = (i[:, 2] > 0.05) & (o[:, 2] > 0.05)
    i, o = i[keep], o[keep]
    mu = LADDER[1]  # a ladder node: no interpolation in μ either
    ctx = mi.BSDFContext()
    got = np.asarray(obj.eval(ctx, interactions(mi, o, mu), vec(mi, i))[0])
    unmasked = np.asarray(lobes.Tabulated(table.values[1], extent=table.extent).evaluate(i, o))
    g2 = np.asarray(lobes.SmithMasking().g2(evolved[1].shape, i, o))
    ref = unmasked * g2
    big = ref > 1e-3 * ref.max()
    assert big.sum() > 20
    assert np.max(np.abs(got[big] - ref[big]) / ref[big]) < 2e-4


def test_pdf_is_the_sampled_slope_density_in_solid_angle(material):
    mi, obj, table, _ = material
    rng = np.random.default_rng(3)
    ctx = mi.BSDFContext()
    for mu in (1.0, 2.5, 9.0):
        i, o = directions_near_lobe(rng, 400)
        got = np.asarray(obj.pdf(ctx, interactions(mi, o, mu), vec(mi, i)))
        ref = reference_pdf(table, mu, o, i)
        big = ref > 1e-3 * ref.max()
        assert np.max(np.abs(got[big] - ref[big]) / ref[big]) < 1e-4, mu


@pytest.mark.parametrize("mu", [1.0, 4.0])
def test_sampled_slopes_follow_the_tabulated_density_chi2(material, mu):
    """χ² of the sampled half-vector slopes against the tabulated density integrated over the bins."""
    mi, obj, table, _ = material
    n = 40000
    rng = np.random.default_rng(4)
    wi = np.tile([[0.3, -0.2, 0.0]], (n, 1))
    wi[:, 2] = np.sqrt(1 - 0.13)
    ctx = mi.BSDFContext()
    bs, _ = obj.sample(ctx, interactions(mi, wi, mu), mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    wo = np.stack([np.asarray(c) for c in (bs.wo.x, bs.wo.y, bs.wo.z)], axis=1)
    h = wi + wo
    m = h[:, :2] / h[:, 2:]
    edges = np.linspace(-0.45, 0.45, 13)
    counts, _, _ = np.histogram2d(m[:, 0], m[:, 1], bins=[edges, edges])
    sub = 8  # midpoint quadrature of the piecewise-bilinear density inside each bin
    fine = (np.arange(12 * sub) + 0.5) / (12 * sub) * 0.9 - 0.45
    mx, my = np.meshgrid(fine, fine, indexing="ij")
    grid = np.stack([mx, my], axis=-1)
    density = sum(
        wk * np.asarray(stats.Tabulated(v, extent=table.extent).density(grid))
        for wk, v in zip(weights(table, mu), table.values)
    )
    prob = density.reshape(12, sub, 12, sub).sum(axis=(1, 3)) * (0.9 / (12 * sub)) ** 2
    expected = n * prob
    observed_outside = n - counts.sum()
    expected_outside = n * (1 - prob.sum())
    use = expected > 5
    chi2 = np.sum((counts[use] - expected[use]) ** 2 / expected[use])
    chi2 += (observed_outside - expected_outside) ** 2 / max(expected_outside, 1.0)
    dof = int(use.sum())
    assert scipy.stats.chi2.sf(chi2, dof) > 1e-3, (chi2, dof)


def test_reciprocity(material):
    check_reciprocity(*material[:2])


@pytest.mark.slow
def test_reciprocity_with_masking(masked):
    check_reciprocity(*masked[:2])


def check_reciprocity(mi, obj):
    rng = np.random.default_rng(5)
    i, o = directions_near_lobe(rng, 300)
    ctx = mi.BSDFContext()
    forward = np.asarray(obj.eval(ctx, interactions(mi, o, 2.0), vec(mi, i))[0]) / i[:, 2]
    backward = np.asarray(obj.eval(ctx, interactions(mi, i, 2.0), vec(mi, o))[0]) / o[:, 2]
    big = forward > 1e-3 * forward.max()
    assert np.max(np.abs(forward[big] - backward[big]) / forward[big]) < 1e-5


@pytest.mark.slow
@pytest.mark.parametrize("form", ["table", "closed"])
def test_albedo_at_most_one_with_unit_amplitude(tables, form):
    """A = 1 and Smith masking of a centred lobe: the directional albedo ∫ eval dω = E[weight] stays ≤ 1 (grazing
    included; Smith's normalisation ∫ G₁(w) (w·h)⁺ D dω_h = cosθ_w). Not for off-centre lobes, whose Λ is that of the
    centred shape (stats.smith_lambda): there the albedo can exceed 1 (docs/render.md, limits)."""
    mi = tables[0]
    centred = lobes.Lobe(stats.Gaussian(cov=[[0.006, 0.002], [0.002, 0.012]]))
    obj = render.bsdf(centred, LAW, mu0=MU0, scales=LADDER, size=48, variant="llvm_ad_rgb", form=form)
    n = 40000
    rng = np.random.default_rng(6)
    ctx = mi.BSDFContext()
    for theta in (0.0, 45.0, 75.0, 88.0):
        t = math.radians(theta)
        wi = np.tile([[math.sin(t), 0.0, math.cos(t)]], (n, 1))
        _, weight = obj.sample(
            ctx, interactions(mi, wi, 3.0), mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
        )
        w = np.asarray(weight[0])
        assert np.all(np.isfinite(w)) and np.all(w >= 0)
        assert w.mean() <= 1 + 4 * w.std() / math.sqrt(n), theta


def test_gradients_reach_the_table_entries(material):
    """eval is linear in the table, so Σ_j table_j ∂eval/∂table_j = eval (Euler): the gradient is the true one."""
    import drjit as dr

    mi, _, table, _ = material
    obj = render.bsdf(None, table, masking=False, mu=2.0, variant="llvm_ad_rgb")  # its own: traverse changes it
    params = mi.traverse(obj)
    dr.enable_grad(params["table"])
    params.update()
    rng = np.random.default_rng(7)
    i, o = directions_near_lobe(rng, 50)
    value = obj.eval(mi.BSDFContext(), interactions(mi, o, 2.0), vec(mi, i))[0]
    total = dr.sum(value)
    dr.backward(total)
    grad = np.asarray(dr.grad(params["table"])).ravel()
    tab = np.asarray(params["table"]).ravel()
    assert np.count_nonzero(grad) > 0
    np.testing.assert_allclose(np.dot(grad, tab), float(np.asarray(total).ravel()[0]), rtol=1e-4)


def test_gradients_of_a_render_reach_the_table(material):
    """mi.render with the scene's parameters: d(mean image)/d(table) through FootprintIntegrator. Lit by a delta light
    alone (reached by emitter sampling only), two segments and no masking, the image is linear in the table, so
    Σ_j table_j ∂mean/∂table_j = mean (Euler)."""
    import drjit as dr

    mi, _, table, _ = material
    obj = render.bsdf(None, table, masking=False, mu=2.0, variant="llvm_ad_rgb")
    scene = mi.load_dict(
        {
            "type": "scene",
            "sensor": {  # straight down, orthographic: every sample sees the same directions (the backward pass
                # re-renders with its own samples; here they cannot differ)
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": 8, "height": 8},
                "sampler": {"type": "independent", "sample_count": 2},
            },
            "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(5), "bsdf": obj},
            "light": {"type": "directional", "direction": [0.2, -0.1, -1.0], "irradiance": 1.0},
        }
    )
    params = mi.traverse(scene)
    dr.enable_grad(params["plane.bsdf.table"])
    params.update()
    image = mi.render(scene, params, integrator=render.FootprintIntegrator(max_depth=2), seed=0)
    mean = dr.mean(image, axis=None)
    dr.backward(mean)
    grad = np.asarray(dr.grad(params["plane.bsdf.table"])).ravel()
    tab = np.asarray(params["plane.bsdf.table"]).ravel()
    assert float(np.asarray(mean).ravel()[0]) > 0 and np.count_nonzero(grad) > 0
    np.testing.assert_allclose(np.dot(grad, tab), float(np.asarray(mean).ravel()[0]), rtol=1e-4)


# -- bad input -------------------------------------------------------------------------------------------------------


def test_bad_statistics_and_options_are_refused_naming_what_is_accepted():
    with pytest.raises(brdfscale.InvalidInputError, match="scale law.*FitResult.*LobeTable"):
        render.bsdf(base_lobe(), {"alpha": 0.1}, mu0=1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="mu0 is required"):
        render.bsdf(base_lobe(), LAW)
    with pytest.raises(brdfscale.InvalidInputError, match="mu must be a positive number"):
        render.bsdf(base_lobe(), LAW, mu0=1.0, mu=-1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="masking must be True"):
        render.bsdf(base_lobe(), LAW, mu0=1.0, masking="beckmann")
    with pytest.raises(brdfscale.InvalidInputError, match="convention must be one of 'beckmann_alpha'"):
        render.export_roughness(LAW, "/nonexistent/x.exr", convention="alpha_squared")
    with pytest.raises(brdfscale.InvalidInputError, match="source must be a synth.HeightField.*without base_lobe"):
        render.export_roughness(LAW, "/nonexistent/x.exr", mu0=1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="source must be a synth.HeightField.*LobeTable"):
        render.export_roughness(np.zeros((8, 8)), "/nonexistent/x.exr")
    rgb = lobes.Beckmann(0.05, amplitude=[0.9, 0.5, 0.2])
    with pytest.raises(brdfscale.InvalidInputError, match=r"renders one channel.*shape \(3,\)"):
        render.bsdf(rgb, LAW, mu0=1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="renders one channel"):
        render.export_roughness(LAW, "/nonexistent/x.exr", base_lobe=rgb, mu0=1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="mirror.*give scales above μ0"):
        render.bsdf(lobes.Mirror(), LAW, mu0=1.0)


@pytest.mark.parametrize(
    "base, law, what",
    [
        (lobes.GGX(0.05), LAW, "GGX"),
        (lobes.Lobe(stats.StudentT(sigma=0.05, nu=2.0)), LAW, "StudentT"),
        (lobes.Beckmann(0.05), stats.ScaledFamily(stats.GGX, stats.WidthLaw(0.3, 1.0, 1.0)), "GGX"),
        (lobes.Lobe(stats.Mixture([0.5, 0.5], [stats.Beckmann(0.05), stats.GGX(0.02)])), LAW, "GGX"),
    ],
)
def test_export_refuses_lobes_without_finite_second_moments(base, law, what):
    """Engines' roughness is second moments: for GGX slopes (or Student-t with ν ≤ 2, or a mixture with such a part)
    the tabulated moments would be the table's truncation (the α of a GGX 0.05 lobe read 0.134, 0.119, 0.118 at
    32², 64², 128² nodes before this refusal), so the export refuses them, before any tabulation."""
    with pytest.raises(brdfscale.InvalidInputError, match=f"{what} slopes have no finite second moments"):
        render.export_roughness(law, "/nonexistent/x.exr", base_lobe=base, mu0=1.0, levels=2, size=16)


def test_the_exports_closed_form_moments_against_the_density_and_the_evolution():
    """``render._export.cumulants`` (mean, covariance) of a disk, a table (its tent sum: h²/6 per axis beyond the node
    sums), a Gaussian mixture and a Student-t against sums of their own densities on a 1201² grid; and
    ``evolved_moments`` (cumulants add) of the off-centre, correlated test lobe evolved by the Beckmann law against
    the Gaussians :func:`brdfscale.evolve` returns in closed form."""
    from brdfscale.render import _export, _material

    x = np.linspace(-3, 3, 1201)
    grid = np.stack(np.meshgrid(x, x, indexing="xy"), -1)
    nodes = np.linspace(-1, 1, 21)
    table = np.exp(-((nodes[None, :] - 0.3) ** 2 + nodes[:, None] ** 2) / 0.1)
    for density, atol in (
        (stats.Disk(0.5, mean=[0.1, 0.2]), 2e-4),  # the disk's edge on the grid
        (stats.Tabulated(table, extent=1.0, center=[0.1, 0.2]), 1e-5),  # the tent term is 1.7e-3
        (
            stats.Mixture([0.6, 0.4], [stats.Beckmann(0.2, mean=[0.3, 0.0]), stats.Beckmann(0.4, mean=[-0.2, 0.1])]),
            1e-9,
        ),
        (stats.StudentT(sigma=0.1, nu=8.0), 1e-7),
    ):
        s = np.asarray(density.density(grid))
        s = s / s.sum()
        mean = np.einsum("yx,yxk->k", s, grid)
        cov = np.einsum("yx,yxk,yxl->kl", s, grid - mean, grid - mean)
        got_mean, got_cov = _export.cumulants(density)
        np.testing.assert_allclose(got_mean, mean, rtol=0, atol=atol, err_msg=repr(density))
        np.testing.assert_allclose(got_cov, cov, rtol=0, atol=atol, err_msg=repr(density))
    scales = 2.0 ** np.arange(4)
    _, evolved, _, _, _ = _material.evolved_lobes(base_lobe(), LAW, mu0=MU0, scales=scales)
    rows = _material.gaussian_parameters(evolved)
    moments = _export.evolved_moments(base_lobe().shape, LAW.at(MU0), [LAW.at(float(mu)) for mu in scales])
    for row, (b, m) in zip(rows, moments):
        c = m - np.outer(b, b)
        np.testing.assert_allclose(b, row[1:3], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose([c[0, 0], c[0, 1], c[1, 1]], row[3:], rtol=1e-12, atol=1e-15)


def test_export_of_statistics_is_an_octave_mip_chain(tmp_path):
    """Level ℓ is the lobe at μ0·2^ℓ over ``resolution >> ℓ`` texels: for a FitResult from its own μ0 (not its
    fitted scales), for measured statistics at most the levels they reach (the default, and ``levels`` beyond them
    refused); a LobeTable's scales must double per level (its first ``levels`` taken); a Student-t lobe of ν = 4
    (finite variance) is exported."""
    fit = fit_result_of_the_law([1.0, 2.0, 3.0, 8.0])
    path = tmp_path / "fit.exr"
    images = render.export_roughness(fit, path, base_lobe=lobes.Beckmann(0.1), levels=3, resolution=4, size=32)
    parts = read_with_openimageio(path)
    assert [float(a["brdfscale.mu"]) for _, a in parts] == [1.0, 2.0, 4.0]
    assert [im["alpha_x"].shape for im in images] == [(4, 4), (2, 2), (1, 1)]
    assert len(render.export_roughness(fit, tmp_path / "all.exr", base_lobe=lobes.Beckmann(0.1), size=16)) == 4
    with pytest.raises(brdfscale.InvalidInputError, match="levels must be at most 4.*measured up to μ = 8"):
        render.export_roughness(fit, tmp_path / "x.exr", base_lobe=lobes.Beckmann(0.1), levels=5, size=16)
    table = render.lobe_table(lobes.Beckmann(0.1), LAW, mu0=1.0, scales=[1.0, 2.0, 4.0], size=16)
    assert len(render.export_roughness(table, tmp_path / "t.exr", levels=2)) == 2
    with pytest.raises(brdfscale.InvalidInputError, match="levels must be at most 3"):
        render.export_roughness(table, tmp_path / "t4.exr", levels=4)
    uneven = render.lobe_table(lobes.Beckmann(0.1), LAW, mu0=1.0, scales=[1.0, 1.5, 2.0], size=16)
    with pytest.raises(brdfscale.InvalidInputError, match="scale doubles per level.*1, 1.5"):
        render.export_roughness(uneven, tmp_path / "u.exr", levels=2)
    with pytest.raises(brdfscale.InvalidInputError, match="already evolved"):
        render.export_roughness(table, tmp_path / "b.exr", base_lobe=lobes.Beckmann(0.1))
    with pytest.raises(brdfscale.InvalidInputError, match="already evolved"):
        render.export_roughness(table, tmp_path / "m.exr", mu0=1.0)
    measured = stats.MeasuredScaleLaw(np.array([1.0, 8.0]), np.array([np.eye(2) * 0.01, np.eye(2) * 0.004]))
    with pytest.raises(brdfscale.InvalidInputError, match=r"mu0 = 16 is outside the range.*\[1, 8\]"):
        render.export_roughness(measured, tmp_path / "o.exr", base_lobe=lobes.Beckmann(0.1), mu0=16.0)
    field = brdfscale.synth.HeightField(np.zeros((8, 8)), spacing=1.0)
    with pytest.raises(brdfscale.InvalidInputError, match="height field's texels carry"):
        render.export_roughness(field, tmp_path / "f.exr", base_lobe=lobes.Beckmann(0.1))
    # a mirror base lobe: level 0 is the mirror (α 0), the coarser levels its evolution
    mirror = render.export_roughness(LAW, tmp_path / "mirror.exr", base_lobe=lobes.Mirror(), mu0=1.0, levels=3)
    assert float(mirror[0]["alpha_x"][0, 0]) == 0.0
    for level in (1, 2):
        alpha = math.sqrt(float(LAW.law(1.0)) ** 2 - float(LAW.law(2.0**level)) ** 2)
        np.testing.assert_allclose(mirror[level]["alpha_x"], alpha, rtol=1e-6)


def fit_result_of_the_law(scales, name="a"):
    """A fitting.FitResult whose covariance differences are the Beckmann law's, ΔΣ_k = (α(μ0)² − α(μ_k)²)/2 · I
    (its one coordinate named ``name``)."""
    from brdfscale import fitting

    diffs = []
    for mu in scales[1:]:
        d = (float(LAW.law(scales[0])) ** 2 - float(LAW.law(mu)) ** 2) / 2
        diffs.append({"mu0": scales[0], "mu": mu, "value": [[d, 0.0], [0.0, d]], "std": [[1e-4, None], [None, 1e-4]]})
    return fitting.FitResult(
        names=(name,),
        theta=np.zeros(1),
        covariance=np.eye(1),
        chi2=1.0,
        n_data=10,
        status="converged",
        starts=[],
        estimates={name: 0.0},
        std={name: 0.1},
        quantiles={name: None},
        eigenvalues=np.ones(1),
        undetermined=[],
        notes=[],
        solver="lm",
        at_bounds=[],
        covariance_differences=diffs,
    )


@pytest.mark.slow
def test_a_fit_result_renders_like_its_law_at_the_fitted_scales():
    """Evolution needs only S(μ0)/S(μ_k): a FitResult's ΔΣ give the law's lobes at the fitted scales."""
    fit = fit_result_of_the_law(LADDER)
    from_fit = render.lobe_table(base_lobe(), fit, scales=LADDER, size=32, extent=0.6)
    from_law = render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=LADDER, size=32, extent=0.6)
    np.testing.assert_allclose(from_fit.values, from_law.values, rtol=1e-9, atol=1e-9 * from_law.values.max())
    with pytest.raises(brdfscale.InvalidInputError, match="differs from the fit's reference scale"):
        render.lobe_table(base_lobe(), fit, mu0=2.0)
    undetermined = fit_result_of_the_law(LADDER)
    undetermined.covariance_differences[0]["value"][0][1] = None
    with pytest.raises(brdfscale.InvalidInputError, match="not all determined"):
        render.lobe_table(base_lobe(), undetermined)


def test_a_fit_of_mixture_increments_is_refused():
    """A material evolves by Gaussian statistics of ΔΣ: the fit of a model with heavy-tailed (mixture) increments
    would render another surface, and is refused naming the alternatives."""
    fit = fit_result_of_the_law(LADDER, name="logit w")
    with pytest.raises(brdfscale.InvalidInputError, match="mixture increments.*increments='gaussian'"):
        render.lobe_table(base_lobe(), fit, scales=LADDER, size=16)


def test_tables_are_deterministic_and_rgb_tables_are_refused(material):
    mi, _, table, _ = material
    again = render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=LADDER, size=48)
    assert np.array_equal(again.values, table.values)
    rgb = brdfscale.exr.LobeTable(table.scales, table.extent, np.repeat(table.values[..., None], 3, axis=-1))
    with pytest.raises(brdfscale.InvalidInputError, match="one-channel lobe tables"):
        render.bsdf(None, rgb, masking=False, variant="llvm_ad_rgb")
    with pytest.raises(brdfscale.InvalidInputError, match="already evolved"):
        render.bsdf(base_lobe(), table, masking=False)
    with pytest.raises(brdfscale.InvalidInputError, match="mu0= and scales= are for statistics"):
        render.bsdf(None, table, mu0=5.0, masking=False)
    with pytest.raises(brdfscale.InvalidInputError, match="mu0= and scales= are for statistics"):
        render.bsdf(None, table, scales=[4.0, 8.0], masking=False)
    with pytest.raises(brdfscale.InvalidInputError, match="output must be one of"):
        render.FootprintIntegrator(output="mu")
    for depth in (0, -3):
        with pytest.raises(brdfscale.InvalidInputError, match="max_depth must be an integer ≥ 1"):
            render.FootprintIntegrator(max_depth=depth)


@pytest.mark.wrong_types
def test_an_export_path_that_is_not_a_path_is_refused():
    """The one write path (files.atomic_write) refuses a path of another type with the library's error."""
    for path, message in (
        (None, "path must be a str or os.PathLike.*NoneType"),
        (b"", "non-empty"),
        ("a\0b.exr", "NUL"),
    ):
        with pytest.raises(brdfscale.InvalidInputError, match=message):
            render.export_roughness(LAW, path, base_lobe=lobes.Beckmann(0.1), mu0=1.0, levels=1, size=16)


@pytest.mark.wrong_types
def test_the_integrators_depth_is_an_integer_python_or_numpy():
    """max_depth by the library's one integer check: a NumPy integer is taken, a float or a bool is refused."""
    llvm()
    for depth in (2.0, True):
        with pytest.raises(brdfscale.InvalidInputError, match="max_depth must be an integer ≥ 1"):
            render.FootprintIntegrator(max_depth=depth, variant="llvm_ad_rgb")
    assert render.FootprintIntegrator(max_depth=np.int64(2), variant="llvm_ad_rgb") is not None  # pyright: ignore


@pytest.mark.wrong_types
def test_a_base_lobe_of_another_type_is_refused():
    with pytest.raises(brdfscale.InvalidInputError, match="base_lobe must be a brdfscale.lobes lobe"):
        render.bsdf("beckmann", LAW, mu0=1.0)  # pyright: ignore[reportArgumentType]


# -- the footprint integrator --------------------------------------------------------------------------------------


def footprint_scene(mi, sensor, plane, bsdf=None):
    return mi.load_dict(
        {
            "type": "scene",
            "sensor": sensor,
            "plane": {
                "type": "rectangle",
                "to_world": mi.ScalarTransform4f().scale(50),
                **({"bsdf": bsdf} if bsdf else {}),
            },
            "light": {"type": "directional", "direction": [0.3, -0.5, -0.8], "irradiance": 2.0},
        }
    )


@pytest.mark.parametrize("spp", [1, 4])
def test_footprint_of_a_plane_below_a_pinhole_camera_is_exact(spp):
    """Looking straight down from height H with a pinhole of horizontal field of view φ on W pixels, one pixel covers
    the square of side 2 (H − near) tan(φ/2)/W of the plane, everywhere (the map image plane → plane is linear).
    Mitsuba 3 starts camera rays, and their differentials, on the near clip plane (perspective.cpp: ``ray.o +=
    ray.d * near_t``), at the height H − near here: a footprint smaller by near/H than the pinhole's."""
    mi = llvm()
    width, height, fov, near = 24, 16, 40.0, 0.3
    sensor = {
        "type": "perspective",
        "near_clip": near,
        "fov": fov,
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3.0], target=[0, 0, 0], up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
        "sampler": {"type": "independent", "sample_count": spp},
    }
    image = np.asarray(
        mi.render(footprint_scene(mi, sensor, 2.0), integrator=render.FootprintIntegrator(output="footprint"))
    )
    expected = 2 * (3.0 - near) * math.tan(math.radians(fov / 2)) / width  # the pixel's, whatever spp
    # float32 ray differentials and uv partials (one-pixel differences of unit directions, ε₃₂/p ≈ 4e-6 each, through
    # normalisations, the plane intersection and a 2×2 solve): ≤ 1.5e-4 seen here
    np.testing.assert_allclose(image[..., 0], expected, rtol=3e-4)


def test_footprint_of_a_tilted_pinhole_camera_against_the_closed_form():
    """A camera pitched 50° from the nadir: a pixel whose ray d makes the angle γ with the axis and meets the plane at
    distance t under incidence θ covers Ω t'²/cosθ with Ω = p² cos³γ (p the pixel pitch on the unit image plane) and
    t' = t − near/cosγ the distance from the ray's start on the near clip plane (where Mitsuba 3 starts the ray and its
    differentials). Mitsuba's differentials are one-pixel finite differences, so the two agree to within the
    footprint's own change across one pixel (computed from the closed form, the tolerance)."""
    mi = llvm()
    width = height = 64
    fov, camera_height, pitch, near = 30.0, 2.0, math.radians(50), 0.2
    target = [0.0, camera_height * math.tan(pitch), 0.0]
    sensor_dict = {
        "type": "perspective",
        "near_clip": near,
        "fov": fov,
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, camera_height], target=target, up=[0, 0, 1]),
        "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}},
        "sampler": {"type": "stratified", "sample_count": 16},
    }
    scene = footprint_scene(mi, sensor_dict, 20.0)
    image = np.asarray(mi.render(scene, integrator=render.FootprintIntegrator(output="footprint")))[..., 0]
    # closed form at pixel centres; ray directions from the camera's frame
    forward = np.array(target) - np.array([0, 0, camera_height])
    forward /= np.linalg.norm(forward)
    p = 2 * math.tan(math.radians(fov / 2)) / width
    left = np.cross([0, 0, 1], forward)
    left /= np.linalg.norm(left)
    up = np.cross(forward, left)
    col, row = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d = forward + ((width / 2 - col) * p)[..., None] * left + ((height / 2 - row) * p)[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    cos_gamma = d @ forward
    t = camera_height / -d[..., 2]
    closed = np.sqrt(p**2 * cos_gamma**3 * (t - near / cos_gamma) ** 2 / -d[..., 2])
    change = np.maximum(np.abs(np.gradient(closed, axis=0)), np.abs(np.gradient(closed, axis=1))) / closed
    assert np.all(np.abs(image - closed) / closed <= change.max())


def test_small_render_on_cpu_is_the_lobe_at_the_pixel_footprint(material):
    """An orthographic camera straight down: every pixel has the footprint 2s/W and sees the plane along z; under a
    directional light of irradiance E every pixel is E·ρ(light, z) at μ = (2s/W)/texel — exactly, since a delta
    light is reached by emitter sampling only. Rendered twice with one seed: identical (determinism)."""
    mi, _, table, evolved = material
    width = 32
    side = 0.6
    texel = 0.015  # μ = (2·0.6/32)/0.015 = 2.5: between the ladder's 1 and 3
    obj = render.bsdf(None, table, masking=False, texel=texel, variant="llvm_ad_rgb")
    light = np.array([-0.25, 0.1, 1.0])
    light /= np.linalg.norm(light)
    scene = mi.load_dict(
        {
            "type": "scene",
            "sensor": {
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0])
                @ mi.ScalarTransform4f().scale([side, side, 1]),
                "film": {"type": "hdrfilm", "width": width, "height": width, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 4},
            },
            "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(5), "bsdf": obj},
            "light": {"type": "directional", "direction": (-light).tolist(), "irradiance": 1.5},
        }
    )
    integrator = render.FootprintIntegrator(max_depth=2)
    first = np.asarray(mi.render(scene, integrator=integrator, seed=3))
    second = np.asarray(mi.render(scene, integrator=integrator, seed=3))
    assert np.array_equal(first, second)
    mu = 2 * side / width / texel
    rho = reference_rho(table, evolved, mu, light[None], np.array([[0.0, 0.0, 1.0]]), masking=False)[0]
    np.testing.assert_allclose(first[..., 0], 1.5 * rho, rtol=1e-4)  # float32
    footprint = np.asarray(mi.render(scene, integrator=render.FootprintIntegrator(output="footprint"), seed=3))
    np.testing.assert_allclose(footprint[..., 0], 2 * side / width, rtol=3e-4)  # float32, as for the pinhole


@pytest.mark.parametrize("masking", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_the_footprint_integrator_agrees_with_mitsubas_path_tracer_at_a_fixed_scale(tables, masking):
    """At a fixed μ the footprint does not matter: the shipped path tracer and Mitsuba's own ``path`` integrator
    (emitter and BSDF sampling, MIS) must agree in expectation — a glossy plane under an environment and a sun, three
    segments. Their mean difference over the image is within 4 standard errors (from the per-pixel differences)."""
    mi = tables[0]
    obj = render.bsdf(base_lobe(), LAW, mu0=MU0, mu=2.0, size=48, masking=masking, variant="llvm_ad_rgb")
    scene = mi.load_dict(
        {
            "type": "scene",
            "sensor": {
                "type": "perspective",
                "fov": 50,
                "to_world": mi.ScalarTransform4f().look_at(origin=[0, -2, 1.2], target=[0, 0, 0], up=[0, 0, 1]),
                "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 64},
            },
            "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(3), "bsdf": obj},
            "ball": {"type": "sphere", "center": [0.3, 0.2, 0.4], "radius": 0.3, "bsdf": {"type": "diffuse"}},
            "sun": {"type": "directional", "direction": [0.1, -1, -0.4], "irradiance": 2.0},
            "sky": {"type": "constant", "radiance": 0.3},
        }
    )
    ours = np.asarray(mi.render(scene, integrator=render.FootprintIntegrator(max_depth=3), seed=1))
    theirs = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 3}), seed=2))
    diff = (ours - theirs)[..., 0].ravel()
    assert abs(diff.mean()) <= 4 * diff.std() / math.sqrt(diff.size), (diff.mean(), diff.std())
    assert ours.mean() > 0.05


def test_the_plugin_classes_are_built_once_per_variant_also_from_many_threads():
    """brdfscale.render._variants.per_variant (the BSDF's and the integrator's classes): one build per variant, the
    same class after that, whichever thread asks first."""
    import threading
    import types

    from brdfscale.render._variants import per_variant

    builds = []

    @per_variant
    def made(mi) -> type:
        """A class per variant."""
        builds.append(mi.variant())
        return type(f"Made_{mi.variant()}", (), {})

    fakes = {name: types.SimpleNamespace(variant=lambda name=name: name) for name in ("scalar_rgb", "llvm_ad_rgb")}
    got = []
    threads = [threading.Thread(target=lambda f=f: got.append(made(f))) for f in [*fakes.values()] * 8]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(builds) == ["llvm_ad_rgb", "scalar_rgb"] and len(set(got)) == 2 and len(got) == 16
    assert made(fakes["scalar_rgb"]).__name__ == "Made_scalar_rgb" and made.__doc__ == "A class per variant."


def test_register_is_idempotent_and_loads_a_lobe_table_from_exr(tmp_path, material):
    mi, _, table, _ = material
    path = tmp_path / "lobes.exr"
    brdfscale.exr.write_lobe_table(path, table)
    assert render.register() == render.register() == "llvm_ad_rgb"
    obj = mi.load_dict({"type": "brdfscale", "filename": str(path), "mu": 3.0, "masking": False})
    direct = render.bsdf(None, table, masking=False, mu=3.0, variant="llvm_ad_rgb")
    rng = np.random.default_rng(8)
    i, o = directions_near_lobe(rng, 100)
    ctx = mi.BSDFContext()
    a = np.asarray(obj.eval(ctx, interactions(mi, o, 0.0), vec(mi, i))[0])
    b = np.asarray(direct.eval(ctx, interactions(mi, o, 0.0), vec(mi, i))[0])
    np.testing.assert_allclose(a, b, rtol=1e-6)  # the table written as float32: float32 in both
    assert mi.load_dict({"type": "brdfscale_footprint", "max_depth": 2}) is not None


def test_a_scenes_brdfscale_bsdf_checks_its_values_as_bsdf_does(tmp_path, material):
    """``{"type": "brdfscale", …}`` in a scene: without ``filename`` it is refused naming it; ``mu`` and ``texel``
    must be positive (``mu`` absent: the footprint) and ``masking`` one of what :func:`render.bsdf` accepts — the
    library's message, under Mitsuba's RuntimeError (Mitsuba wraps what a plugin's constructor raises)."""
    mi, _, table, _ = material
    path = tmp_path / "lobes.exr"
    brdfscale.exr.write_lobe_table(path, table)
    render.register()
    cases = [
        ({}, "needs filename="),
        ({"filename": str(path), "mu": -4.0}, "mu must be a positive number"),
        ({"filename": str(path), "mu": float("nan")}, "mu must be a positive number"),
        ({"filename": str(path), "texel": 0.0}, "texel must be a positive number"),
        ({"filename": str(path), "texel": -0.01}, "texel must be a positive number"),
        ({"filename": str(path), "masking": "false"}, "masking must be True"),
    ]
    for props, message in cases:
        with pytest.raises((brdfscale.InvalidInputError, RuntimeError), match=message):
            mi.load_dict({"type": "brdfscale", **props})
    none = mi.load_dict({"type": "brdfscale", "filename": str(path), "masking": "none"})
    smith = mi.load_dict({"type": "brdfscale", "filename": str(path), "masking": "smith", "mu": 3.0})
    assert none.host.masking is None and none.host.mu is None
    assert isinstance(smith.host.masking, lobes.SmithMasking) and smith.host.mu == 3.0


# -- the scalar variant (a process of its own: the variant is process-wide) -------------------------------------------


SCALAR_CHECK = """
import numpy as np, jax
jax.config.update("jax_enable_x64", True)
import drjit as dr
import brdfscale
from brdfscale import render, _mitsuba, lobes, stats
mi = _mitsuba.mitsuba("scalar_rgb")
law = stats.ScaledFamily(stats.Beckmann, stats.WidthLaw(0.3, 1.0, 1.0))
base = lobes.Lobe(stats.Gaussian(cov=[[0.006, 0.002], [0.002, 0.012]], mean=[0.04, -0.03]))
table = render.lobe_table(base, law, mu0=1.0, scales=[1.0, 3.0, 9.0], size=48)
obj = render.bsdf(None, table, masking=False)
rng = np.random.default_rng(0)
ctx = mi.BSDFContext()
def draw(mu):  # o, its mirror direction i about a half-vector near the lobe, o's interaction at footprint mu
    o = rng.normal(size=3); o[2] = abs(o[2]) + 0.5; o /= np.linalg.norm(o)
    m = np.array([0.04, -0.03]) + 0.15 * rng.normal(size=2)
    h = np.array([m[0], m[1], 1.0]); h /= np.linalg.norm(h)
    i = 2 * o.dot(h) * h - o
    if i[2] < 0.05:
        return o, i, None
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(*o); si.dp_du = mi.Vector3f(1, 0, 0); si.dp_dv = mi.Vector3f(0, 1, 0)
    si.duv_dx = mi.Vector2f(mu, 0); si.duv_dy = mi.Vector2f(0, mu)
    return o, i, si
worst = 0.0
for mu in (1.0, 2.0, 9.0):
    w = np.log(table.scales); t = np.log(mu); k = min(np.searchsorted(w, t, side="right") - 1, 1)
    f = (t - w[k]) / (w[k + 1] - w[k])
    for _ in range(60):
        o, i, si = draw(mu)
        if si is None:
            continue
        got = obj.eval(ctx, si, mi.Vector3f(*i))[0]
        ref = (1 - f) * float(lobes.Tabulated(table.values[k], extent=table.extent).evaluate(i, o)) + f * float(
            lobes.Tabulated(table.values[k + 1], extent=table.extent).evaluate(i, o))
        pdf = obj.pdf(ctx, si, mi.Vector3f(*i))
        bs, weight = obj.sample(ctx, si, 0.5, mi.Point2f(*rng.random(2)))
        assert abs(bs.pdf - obj.pdf(ctx, si, bs.wo)) <= 1e-5 * bs.pdf, (bs.pdf, obj.pdf(ctx, si, bs.wo))
        if ref > 1e-3:
            worst = max(worst, abs(got - ref) / ref)
closed = render.bsdf(base, law, mu0=1.0, scales=[1.0, 3.0, 9.0])  # the closed form, Smith-masked
assert "form=closed" in str(closed)
for mu in (1.0, 3.0):
    lobe = brdfscale.evolve(base, law.at(1.0), law.at(mu))
    for _ in range(40):
        o, i, si = draw(mu)
        if si is None:
            continue
        got = closed.eval(ctx, si, mi.Vector3f(*i))[0]
        ref = float(lobe.evaluate(i, o, masking=lobes.SmithMasking()))
        bs, weight = closed.sample(ctx, si, 0.5, mi.Point2f(*rng.random(2)))
        assert abs(bs.pdf - closed.pdf(ctx, si, bs.wo)) <= 1e-5 * bs.pdf
        if ref > 1e-3:
            worst = max(worst, abs(got - ref) / ref)
print("WORST", worst)
"""


@pytest.mark.slow
def test_scalar_variant_eval_matches_the_lobe_and_sampling_its_pdf():
    run = subprocess.run(
        [sys.executable, "-c", SCALAR_CHECK], capture_output=True, text=True, timeout=600, cwd=Path(__file__).parent
    )
    assert run.returncode == 0, run.stderr[-3000:]
    worst = float(run.stdout.split("WORST")[-1])
    assert worst < 1e-4


# -- engine export ----------------------------------------------------------------------------------------------------


def read_with_openimageio(path):
    """Every part (subimage) of an EXR: (channels dict, attributes dict) — OpenImageIO, not OpenEXR's bindings."""
    oiio = pytest.importorskip("OpenImageIO")
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    parts = []
    k = 0
    while inp.seek_subimage(k, 0):
        spec = inp.spec()
        pixels = inp.read_image(k, 0, 0, spec.nchannels, "float")
        channels = {name: pixels[..., c] for c, name in enumerate(spec.channelnames)}
        attrs = {
            name: spec.getattribute(name)
            for name in ("brdfscale.convention", "brdfscale.convention_text", "brdfscale.mip_level", "brdfscale.mu")
        }
        parts.append((channels, attrs))
        k += 1
    inp.close()
    return parts


@pytest.mark.slow
def test_export_of_a_scale_law_reads_back_with_the_closed_form_alpha(tmp_path):
    """A Beckmann lobe α0 evolved by a Beckmann width law: α(μ)² = α0² + α_law(μ0)² − α_law(μ)² per axis (Gaussian
    covariances add), read back by OpenImageIO from the mip chain."""
    path = tmp_path / "rough.exr"
    render.export_roughness(LAW, path, base_lobe=lobes.Beckmann(0.1), mu0=1.0, convention="beckmann_alpha", levels=4)
    parts = read_with_openimageio(path)
    assert len(parts) == 4
    for level, (channels, attrs) in enumerate(parts):
        mu = 2.0**level
        alpha = math.sqrt(0.1**2 + float(LAW.law(1.0)) ** 2 - float(LAW.law(mu)) ** 2)
        assert attrs["brdfscale.convention"] == "beckmann_alpha" and attrs["brdfscale.mip_level"] == level
        assert "not alpha squared" in attrs["brdfscale.convention_text"]
        assert float(attrs["brdfscale.mu"]) == mu
        # Gaussian lobes: their moments in closed form, written as float32
        np.testing.assert_allclose(channels["alpha_x"], alpha, rtol=1e-6)
        np.testing.assert_allclose(channels["alpha_y"], alpha, rtol=1e-6)
        np.testing.assert_allclose(channels["rho"], 0.0, atol=1e-7)
    # a heavy-tailed Student-t lobe (ν = 2.5: covariance σ² ν/(ν − 2), 5 σ²): its moments in closed form too (a table
    # of it loses 16 % of α in its truncated tails)
    student = tmp_path / "student.exr"
    sigma, nu = 0.05, 2.5
    render.export_roughness(
        LAW,
        student,
        base_lobe=lobes.Lobe(stats.StudentT(sigma=sigma, nu=nu)),
        mu0=1.0,
        convention="beckmann_alpha",
        levels=3,
    )
    for level, (channels, _) in enumerate(read_with_openimageio(student)):
        mu = 2.0**level
        variance = sigma**2 * nu / (nu - 2) + (float(LAW.law(1.0)) ** 2 - float(LAW.law(mu)) ** 2) / 2
        np.testing.assert_allclose(channels["alpha_x"], math.sqrt(2 * variance), rtol=1e-6)
        np.testing.assert_allclose(channels["alpha_y"], math.sqrt(2 * variance), rtol=1e-6)


def test_export_of_a_height_field_is_lean_mip_mapping(tmp_path):
    """Per-texel moments of the pixel facets: level ℓ's texel is the mean of its 2^ℓ × 2^ℓ pixels, and its α the
    covariance of those pixels' slopes — checked against NumPy on the facet slopes (synth.facet_slopes at 2^ℓ
    pitches gives the mean slope independently)."""
    field = brdfscale.synth.named_surface("anisotropic", size=32, seed=1)
    lean, ggx = tmp_path / "lean.exr", tmp_path / "ggx.exr"
    render.export_roughness(field, lean, convention="lean_moments")
    render.export_roughness(field, ggx, convention="ggx_alpha")
    parts, alphas = read_with_openimageio(lean), read_with_openimageio(ggx)
    assert [p[0]["B_x"].shape for p in parts] == [(32 >> k, 32 >> k) for k in range(6)]
    pixel = brdfscale.synth.facet_slopes(field, float(min(field.spacing)))
    for level in (0, 2, 4):
        b = 2**level
        block_mean = brdfscale.synth.facet_slopes(field, b * float(min(field.spacing)))
        np.testing.assert_allclose(parts[level][0]["B_x"], block_mean[..., 0], rtol=1e-5, atol=1e-6)
        blocks = pixel.reshape(32 // b, b, 32 // b, b, 2)
        cov_xx = blocks[..., 0].var(axis=(1, 3))
        np.testing.assert_allclose(alphas[level][0]["alpha_x"], np.sqrt(2 * cov_xx), rtol=1e-4, atol=1e-5)
        assert alphas[level][1]["brdfscale.convention"] == "ggx_alpha"


def test_export_of_a_field_of_rectangular_pixels(tmp_path):
    """Rectangular pixels (Δx ≠ Δy, beyond the square tolerance) are exported too: level ℓ's mean slope is the mean
    of its 2^ℓ × 2^ℓ pixel slopes (synth.pixel_slopes, which takes each axis's own pitch), its μ 2^ℓ √(Δx Δy)."""
    heights = np.random.default_rng(3).standard_normal((16, 16)) * 1e-7
    field = brdfscale.topography.from_array(heights, (1e-6, 2e-6), unit="m", detrend=None)
    path = tmp_path / "rect.exr"
    render.export_roughness(field, path, convention="lean_moments", levels=3)
    parts = read_with_openimageio(path)
    pixel = brdfscale.synth.pixel_slopes(field)
    h, w = pixel.shape[:2]
    for level in range(3):
        b = 2**level
        blocks = pixel[: h // 4 * 4, : w // 4 * 4].reshape(h // 4 * 4 // b, b, w // 4 * 4 // b, b, 2)
        np.testing.assert_allclose(parts[level][0]["B_y"], blocks[..., 1].mean(axis=(1, 3)), rtol=1e-5, atol=1e-6)
        assert float(parts[level][1]["brdfscale.mu"]) == pytest.approx(b * math.sqrt(2e-12), rel=1e-12)


# -- docs/render.md ----------------------------------------------------------------------------------------------------


def test_the_guides_example_runs(monkeypatch, tmp_path):
    """The python block of docs/render.md, as a user would run it (LLVM variant; its image is finite and lit)."""
    llvm()
    page = Path(__file__).resolve().parents[1] / "docs" / "render.md"
    text = page.read_text(encoding="utf-8")
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    assert len(blocks) == 1
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__render_guide__"}
    exec(compile(blocks[0], str(page), "exec"), namespace)  # noqa: S102 — the page's own example
    image = np.asarray(namespace["image"])
    assert image.shape == (32, 32, 3) and np.all(np.isfinite(image)) and image.max() > 0
