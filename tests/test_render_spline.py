"""brdfscale.render's spline form: the B-spline numerics against SciPy and Dr.Jit, the rendered lobe against the exactly
evolved one.

References nobody here wrote: SciPy's ``BSpline`` (the same coefficients evaluated by another implementation), Dr.Jit's
``Texture3f.eval_cubic`` (what the plugin renders with), closed-form functions (a cubic reproduced exactly, a smooth
function's O(h⁴) convergence), and ``brdfscale.evolve``'s lobes evaluated by ``AbstractLobe.evaluate``.
"""

import math

import numpy as np
import pytest
import scipy.interpolate

import brdfscale
from brdfscale import _mitsuba, exr, lobes, render, stats
from brdfscale._errors import InvalidInputError
from brdfscale.render import _spline


LAW = stats.ScaledFamily(stats.Beckmann, stats.WidthLaw(0.3, 1.0, 1.0))
MU0 = 1.0


def base_lobe():
    """Anisotropic, correlated and off-centre (tests/test_render.py's)."""
    return lobes.Lobe(stats.Gaussian(cov=[[0.006, 0.002], [0.002, 0.012]], mean=[0.04, -0.03]))


# -- the numerics (NumPy, SciPy) ---------------------------------------------------------------------------------


def test_prefiltered_coefficients_interpolate_and_scipy_evaluates_the_same_spline():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(7, 5, 6))
    c = _spline.prefilter(v)
    np.testing.assert_allclose(_spline.on_grid(c, [np.arange(7), np.arange(5), np.arange(6)]), v, atol=1e-12)
    # one axis against SciPy: the clamped coefficients extended explicitly, B-spline j centred at the integer j
    line = rng.normal(size=9)
    coefficients = _spline.prefilter(line)
    k = np.arange(-3, 12)
    extended = coefficients[np.clip(k, 0, 8)]
    spline = scipy.interpolate.BSpline(np.arange(len(extended) + 4) - 5.0, extended, 3)
    x = rng.uniform(0.0, 8.0, 200)
    np.testing.assert_allclose(_spline.on_grid(coefficients, [x]), spline(x), atol=1e-12)


def test_a_run_reproduces_a_cubic_exactly_and_converges_as_h4_to_its_ends():
    x = np.linspace(0.0, 1.0, 6)
    cubic = 2 * x**3 - x**2 + 0.5 * x - 1
    c = _spline.runs_coefficients(cubic, [0, 5])
    t = np.linspace(0.0, 5.0, 101)
    np.testing.assert_allclose(
        _spline.on_grid(c, [t + _spline.GHOSTS]), 2 * (t / 5) ** 3 - (t / 5) ** 2 + t / 10 - 1, atol=1e-12
    )
    errors = []
    for n in (17, 33, 65):
        x = np.linspace(0.0, 1.0, n)
        c = _spline.runs_coefficients(np.exp(2 * x) * np.sin(3 * x), [0, n - 1])
        t = np.linspace(0.0, n - 1.0, 2001)  # the ends included
        errors.append(
            np.max(np.abs(_spline.on_grid(c, [t + _spline.GHOSTS]) - np.exp(2 * t / (n - 1)) * np.sin(3 * t / (n - 1))))
        )
    assert errors[1] < errors[0] / 10 and errors[2] < errors[1] / 10, errors  # 16× per halving in the limit
    # clamped ends alone (what eval_cubic does at a texture's edge) flatten the slope there: an O(h) error
    x = np.linspace(0.0, 1.0, 65)
    clamped = _spline.on_grid(_spline.prefilter(np.exp(2 * x) * np.sin(3 * x)), [np.linspace(0.0, 64.0, 2001)])
    assert np.max(np.abs(clamped - np.exp(2 * t / 64) * np.sin(3 * t / 64))) > 100 * errors[2]


def test_periodic_axis_interpolates_and_wraps():
    phi = 2 * np.pi * np.arange(12) / 12
    f = np.cos(phi) + 0.3 * np.sin(2 * phi)
    c = _spline.prefilter(f, periodic=(0,))
    assert c.shape == (12 + 2 * _spline.PERIODIC_PAD,)
    pad = _spline.PERIODIC_PAD
    np.testing.assert_allclose(_spline.on_grid(c, [np.arange(12) + pad]), f, atol=1e-12)
    x = np.linspace(-1.0, 12.0, 131)  # across φ = 0 = 2π from both sides
    got = _spline.on_grid(c, [x + pad])
    exact = np.cos(2 * np.pi * x / 12) + 0.3 * np.sin(4 * np.pi * x / 12)
    assert np.max(np.abs(got - exact)) < 5e-3


def test_runs_split_a_ladder_where_its_ln_mu_step_changes():
    assert _spline.runs(np.log([1, 2, 4, 8, 12, 18, 27, 40])) == [0, 3, 6, 7]
    assert _spline.runs(np.log([1.0, 2.0])) == [0, 1]
    assert _spline.runs(np.log(np.geomspace(1, 9, 5))) == [0, 4]


# -- Dr.Jit's eval_cubic is the same sum ----------------------------------------------------------------------------


def llvm():
    pytest.importorskip("mitsuba")
    problem = _mitsuba.available("llvm_ad_rgb")
    if problem:
        pytest.skip(problem)
    return _mitsuba.mitsuba("llvm_ad_rgb")


def test_drjit_eval_cubic_is_the_host_spline():
    mi = llvm()
    rng = np.random.default_rng(1)
    c = rng.normal(size=(5, 6, 9))  # (depth, height, width)
    tex = mi.Texture3f(mi.TensorXf(c[..., None].astype(np.float32)))
    x, y, z = rng.uniform(-1, 9, 300), rng.uniform(-1, 6, 300), rng.uniform(-1, 5, 300)
    got = np.asarray(tex.eval_cubic(mi.Point3f((x + 0.5) / 9, (y + 0.5) / 6, (z + 0.5) / 5))[0])
    want = np.array([_spline.on_grid(c, [[d], [b], [a]]).item() for d, b, a in zip(z, y, x)])
    np.testing.assert_allclose(got, want, atol=2e-5)


# -- the rendered lobe -------------------------------------------------------------------------------------------


def eval_errors(mi, obj, law, mus, rng, masking, n=300):
    """The largest relative error of eval against brdfscale.evolve(base, law.at(μ0), law.at(μ)) evaluated with
    ``masking``, per μ, at directions whose half-vector slope is near the lobe, where ρ > 1e-3 of its max."""
    import drjit as dr

    worst = []
    for mu in mus:
        lobe = brdfscale.evolve(base_lobe(), law.at(MU0), law.at(float(mu)))
        o = rng.normal(size=(4 * n, 3))
        o[:, 2] = np.abs(o[:, 2])
        o /= np.linalg.norm(o, axis=1, keepdims=True)
        m = np.array([0.04, -0.03]) + 0.2 * rng.normal(size=(4 * n, 2))
        h = np.concatenate([m, np.ones((4 * n, 1))], axis=1)
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        i = 2 * np.sum(o * h, axis=1, keepdims=True) * h - o
        keep = (o[:, 2] > 0.3) & (i[:, 2] > 0.05)
        i, o = i[keep][:n], o[keep][:n]
        si = dr.zeros(mi.SurfaceInteraction3f, len(o))
        si.wi = mi.Vector3f(*[np.ascontiguousarray(o[:, k]) for k in range(3)])
        si.dp_du, si.dp_dv = mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0)
        si.duv_dx = mi.Vector2f(np.full(len(o), float(mu)), 0.0)
        si.duv_dy = mi.Vector2f(0.0, np.full(len(o), float(mu)))
        wo = mi.Vector3f(*[np.ascontiguousarray(i[:, k]) for k in range(3)])
        got = np.asarray(obj.eval(mi.BSDFContext(), si, wo)[0])
        ref = np.asarray(lobe.evaluate(i, o, masking=masking))
        big = ref > 1e-3 * ref.max()
        worst.append(float(np.max(np.abs(got[big] / ref[big] - 1))))
    return np.array(worst)


@pytest.mark.slow  # 10 s on 2 cores
def test_a_refined_spline_holds_its_tolerance_at_random_scales():
    """[1, 4] to 1e-3 with the spline form (its runs refined, its grid refined), unmasked: eval within 1e-3 of the
    exactly evolved lobe at random scales and at the first midpoint, the finest steps near μ0."""
    mi = llvm()
    obj = render.bsdf(
        base_lobe(),
        LAW,
        mu0=MU0,
        scales=[1.0, 4.0],
        size=33,
        tolerance=1e-3,
        form="spline",
        masking=False,
        variant="llvm_ad_rgb",
    )
    host = obj.host
    assert host.form == "spline" and "form=spline" in str(obj)
    ladder = np.exp(host.log_mu)
    np.testing.assert_allclose(ladder[[0, -1]], [1.0, 4.0], rtol=1e-12)
    assert host.breaks[0] == 0 and host.breaks[-1] == len(ladder) - 1
    rng = np.random.default_rng(2)
    mus = [math.sqrt(ladder[0] * ladder[1]), *np.exp(rng.uniform(0.0, math.log(4.0), 3))]
    assert np.all(eval_errors(mi, obj, LAW, mus, rng, lobes.NoMasking()) < 1e-3)
    steps = np.diff(np.log(ladder))
    assert steps[0] < steps[-1] / 4  # finest near μ0, where the lobe widens fastest


@pytest.mark.slow
def test_a_masked_spline_holds_its_tolerance_and_is_reciprocal():
    """With Smith masking (G₁ tables interpolated by the spline too) at random scales, the tolerance 1e-3 holds
    for the masked lobe; f = eval/cosθ_o is symmetric; the sampler's weight is eval/pdf."""
    import drjit as dr

    mi = llvm()
    obj = render.bsdf(
        base_lobe(), LAW, mu0=MU0, scales=[1.0, 4.0], size=33, tolerance=1e-3, form="spline", variant="llvm_ad_rgb"
    )
    rng = np.random.default_rng(3)
    errors = eval_errors(mi, obj, LAW, np.exp(rng.uniform(0.0, math.log(4.0), 4)), rng, lobes.SmithMasking())
    assert np.all(errors < 1e-3), errors
    n = 2000
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    wi = rng.normal(size=(n, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.3
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    si.wi = mi.Vector3f(*[np.ascontiguousarray(wi[:, k]) for k in range(3)])
    si.dp_du, si.dp_dv = mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0)
    si.duv_dx, si.duv_dy = mi.Vector2f(np.full(n, 2.0), 0.0), mi.Vector2f(0.0, np.full(n, 2.0))
    bs, weight = obj.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    value = np.asarray(obj.eval(mi.BSDFContext(), si, bs.wo)[0])
    pdf = np.asarray(bs.pdf)
    ok = pdf > 0
    np.testing.assert_allclose(np.asarray(weight[0])[ok], value[ok] / pdf[ok], rtol=1e-4)
    np.testing.assert_allclose(pdf[ok], np.asarray(obj.pdf(mi.BSDFContext(), si, bs.wo))[ok], rtol=1e-5)
    wo = np.stack([np.asarray(c) for c in (bs.wo.x, bs.wo.y, bs.wo.z)], axis=1)[ok & (np.asarray(bs.wo.z) > 0.05)]
    back = dr.zeros(mi.SurfaceInteraction3f, len(wo))
    back.wi = mi.Vector3f(*[np.ascontiguousarray(wo[:, k]) for k in range(3)])
    back.dp_du, back.dp_dv = mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0)
    back.duv_dx, back.duv_dy = mi.Vector2f(np.full(len(wo), 2.0), 0.0), mi.Vector2f(0.0, np.full(len(wo), 2.0))
    keep = ok & (np.asarray(bs.wo.z) > 0.05)
    forward = value[keep] / wo[:, 2]
    w_in = mi.Vector3f(*[np.ascontiguousarray(wi[keep][:, k]) for k in range(3)])
    backward = np.asarray(obj.eval(mi.BSDFContext(), back, w_in)[0]) / wi[keep][:, 2]
    big = forward > 1e-3 * forward.max()
    np.testing.assert_allclose(backward[big], forward[big], rtol=1e-5)


@pytest.mark.slow  # 6 s on 2 cores
def test_a_measured_law_breaks_the_ladder_at_its_own_scales():
    """A MeasuredScaleLaw is linear in ln μ between its scales: the lobe has kinks there, so each is a break of the
    spline ladder (one spline across a kink would smear it over its neighbours)."""
    law = stats.MeasuredScaleLaw(
        np.array([1.0, 2.0, 4.0]),
        np.array([[[0.03, 0.004], [0.004, 0.02]], [[0.02, 0.003], [0.003, 0.014]], [[0.011, 0.0], [0.0, 0.01]]]),
    )
    mi = llvm()
    obj = render.bsdf(
        base_lobe(),
        law,
        mu0=MU0,
        scales=np.geomspace(1.0, 4.0, 5),
        size=33,
        tolerance=1e-3,
        form="spline",
        masking=False,
        variant="llvm_ad_rgb",
    )
    ladder = np.exp(obj.host.log_mu)
    assert set(ladder[obj.host.breaks].round(12)) >= {1.0, 2.0, 4.0}  # the law's scales are breaks
    rng = np.random.default_rng(4)
    assert np.all(eval_errors(mi, obj, law, [2.0, 1.9, 2.1, 3.0], rng, lobes.NoMasking()) < 1e-3)  # at and by a kink


def test_a_lobe_table_renders_as_a_spline_with_its_breaks_and_refuses_bad_ones(tmp_path):
    llvm()
    table = render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=[1.0, 2.0, 4.0, 6.0], size=24)
    obj = render.bsdf(None, table, masking=False, form="spline", variant="llvm_ad_rgb")
    assert obj.host.breaks == [0, 2, 3]  # steps ln 2, ln 2, ln 1.5
    path = tmp_path / "lobes.exr"
    marked = exr.LobeTable(
        scales=table.scales, values=table.values, extent=table.extent, metadata={"spline_breaks": [0, 1, 3]}
    )
    exr.write_lobe_table(str(path), marked)
    with pytest.raises(InvalidInputError, match="equal ln-μ steps between breaks"):
        render.bsdf(None, exr.read_lobe_table(str(path)), masking=False, form="spline", variant="llvm_ad_rgb")
    for bad in ([0, 2], [1, 3], [0, 0, 3], "0,3"):
        with pytest.raises(InvalidInputError, match="spline_breaks"):
            render.bsdf(
                None,
                exr.LobeTable(
                    scales=table.scales, values=table.values, extent=table.extent, metadata={"spline_breaks": bad}
                ),
                masking=False,
                form="spline",
                variant="llvm_ad_rgb",
            )
    law = stats.MeasuredScaleLaw(np.array([1.0, 2.0, 4.0]), np.array([np.eye(2) * v for v in (0.03, 0.02, 0.01)]))
    recorded = render.lobe_table(base_lobe(), law, mu0=MU0, scales=np.geomspace(1.0, 4.0, 5), size=24, form="spline")
    assert recorded.metadata["spline_breaks"] == [0, 2, 4]  # the law's scales, written with the table
    exr.write_lobe_table(str(tmp_path / "measured.exr"), recorded)
    again = render.bsdf(
        None, exr.read_lobe_table(str(tmp_path / "measured.exr")), masking=False, form="spline", variant="llvm_ad_rgb"
    )
    assert again.host.breaks == [0, 2, 4]
    with pytest.raises(InvalidInputError, match="'table' or 'spline'"):
        render.lobe_table(base_lobe(), LAW, mu0=MU0, scales=[1.0, 2.0], form="closed")
    with pytest.raises(InvalidInputError, match="'auto', 'table' or 'spline'"):
        render.bsdf(None, table, form="closed", variant="llvm_ad_rgb")


def test_the_spline_coefficients_receive_gradients():
    """eval is linear in the coefficients: Σ c ∂eval/∂c = eval (Euler's identity), on llvm_ad_rgb."""
    import drjit as dr

    mi = llvm()
    obj = render.bsdf(
        base_lobe(), LAW, mu0=MU0, scales=[1.0, 2.0, 4.0], size=24, form="spline", masking=False, variant="llvm_ad_rgb"
    )
    params = mi.traverse(obj)
    dr.enable_grad(params["coefficients"])
    params.update()
    n = 50
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(0.1, 0.05, math.sqrt(1 - 0.0125))
    si.dp_du, si.dp_dv = mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0)
    si.duv_dx, si.duv_dy = mi.Vector2f(np.full(n, 1.7), 0.0), mi.Vector2f(0.0, np.full(n, 1.7))
    rng = np.random.default_rng(5)
    m = np.array([0.04, -0.03]) + 0.05 * rng.normal(size=(n, 2))
    h = np.concatenate([m, np.ones((n, 1))], axis=1)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    o = np.array([0.1, 0.05, math.sqrt(1 - 0.0125)])
    i = 2 * (h @ o)[:, None] * h - o
    total = dr.sum(obj.eval(mi.BSDFContext(), si, mi.Vector3f(*[np.ascontiguousarray(i[:, k]) for k in range(3)]))[0])
    dr.backward(total)
    grad = np.asarray(dr.grad(params["coefficients"])).ravel()
    values = np.asarray(params["coefficients"]).ravel()
    assert np.count_nonzero(grad) > 0
    np.testing.assert_allclose(np.dot(grad, values), float(np.asarray(total).ravel()[0]), rtol=1e-3)
