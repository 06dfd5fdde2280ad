"""Slope statistics: normalisation, transforms, references (Mitsuba, SciPy), scale laws, errors."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate as si
import scipy.special as sp
from hypothesis import example, given, settings, strategies as st

import brdfscale as bs
from brdfscale import stats


def _grid(extent, n):
    x = np.linspace(-extent, extent, n)
    X, Y = np.meshgrid(x, x, indexing="xy")
    return x, np.stack([X, Y], -1), (x[1] - x[0]) ** 2


def _numerical_cf(dens, W, extent, n):
    """∫ s(m) e^{−iW·m} d²m by a fine Riemann sum (spectrally accurate for smooth densities)."""
    _, M, dA = _grid(extent, n)
    vals = np.asarray(dens.density(jnp.asarray(M)))
    return np.array([np.sum(vals * np.exp(-1j * (M @ w))) * dA for w in W])


SMOOTH = [
    stats.Beckmann(0.2),
    stats.Beckmann(alpha_x=0.1, alpha_y=0.3, mean=[0.02, -0.01]),
    stats.Gaussian(cov=[[0.01, 0.004], [0.004, 0.02]], mean=[0.05, 0.0]),
    stats.Mixture([0.7, 0.3], [stats.Beckmann(0.1, mean=[0.03, 0.0]), stats.Beckmann(0.15, mean=[-0.07, 0.0])]),
]


@pytest.mark.parametrize("dens", SMOOTH)
def test_smooth_density_normalised_and_cf_matches_quadrature(dens):
    W = np.array([[0.0, 0.0], [3.0, -2.0], [10.0, 4.0], [-7.0, 15.0]])
    ours = np.asarray(dens.cf(jnp.asarray(W)))
    ref = _numerical_cf(dens, W, 2.0, 801)
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    assert abs(ours[0] - 1) < 1e-15


def test_ggx_cf_closed_form_and_density_normalisation():
    alpha = 0.25
    g = stats.GGX(alpha)
    k = np.logspace(-4, 2, 50)
    W = np.stack([k, np.zeros_like(k)], -1)
    np.testing.assert_allclose(np.asarray(g.cf(jnp.asarray(W))).real, alpha * k * sp.k1(alpha * k), rtol=1e-13)
    # radial normalisation ∫ 2π r s(r) dr = 1 (heavy tails: adaptive quadrature)
    mass, _ = si.quad(lambda r: 2 * np.pi * r * float(g.density(jnp.array([r, 0.0]))), 0, np.inf, limit=200)
    assert abs(mass - 1) < 1e-10
    # anisotropic: S(W) = |A W| K1(|A W|)
    ga = stats.GGX(alpha_x=0.1, alpha_y=0.3)
    w = np.array([2.0, -3.0])
    r = np.hypot(0.1 * 2.0, 0.3 * 3.0)
    assert abs(complex(ga.cf(jnp.asarray(w))) - r * sp.k1(r)) < 1e-14


def test_disk_cf_and_density():
    d = stats.Disk(0.1)
    k = np.linspace(0.0, 400.0, 41)
    W = np.stack([k, np.zeros_like(k)], -1)
    ref = np.where(k == 0, 1.0, 2 * sp.j1(0.1 * np.where(k == 0, 1, k)) / (0.1 * np.where(k == 0, 1, k)))
    np.testing.assert_allclose(np.asarray(d.cf(jnp.asarray(W))).real, ref, atol=1e-14)
    assert float(d.density(jnp.array([0.05, 0.05]))) == pytest.approx(1 / (np.pi * 0.01))
    assert float(d.density(jnp.array([0.1, 0.05]))) == 0.0


@pytest.mark.parametrize("kind", ["Beckmann", "GGX"])
def test_against_mitsuba_microfacet_distribution(kind):
    """Mitsuba's D(h) times cos⁴θ is the slope density P22 (docs/conventions.md §1). Mitsuba's pip build is
    float32 only, so agreement is to float32 rounding (≤ 2e-6 relative)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    ax, ay = 0.2, 0.35
    dist = mi.MicrofacetDistribution(getattr(mi.MicrofacetType, kind), ax, ay, False)
    ours = stats.Beckmann(alpha_x=ax, alpha_y=ay) if kind == "Beckmann" else stats.GGX(alpha_x=ax, alpha_y=ay)
    rng = np.random.default_rng(0)
    m = rng.normal(scale=0.3, size=(200, 2))
    n = np.concatenate([m, np.ones((200, 1))], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    D = np.array([dist.eval(mi.Vector3f(*v)) for v in n])
    P22 = D * n[:, 2] ** 4
    # float32 rounding of Mitsuba's exp(−x) / (1 + x)^−2 grows with the exponent x
    x = (m[:, 0] / ax) ** 2 + (m[:, 1] / ay) ** 2
    rtol = 4 * np.finfo(np.float32).eps * (4 + x)
    ours_vals = np.asarray(ours.density(jnp.asarray(m)))
    assert np.all(np.abs(ours_vals / P22 - 1) <= rtol)


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
def test_tabulated_cf_is_exact_for_the_interpolant_and_from_samples_mean():
    rng = np.random.default_rng(1)
    samples = rng.normal(size=(20000, 2)) * [0.08, 0.05] + [0.02, 0.0]
    t = stats.Tabulated.from_samples(samples, extent=0.5, bins=65)
    W = np.array([[0.0, 0.0], [4.0, 1.0], [-9.0, 12.0], [30.0, -20.0]])
    ref = _numerical_cf(t, W, 0.5, 65 * 16 + 1)  # the interpolant is piecewise bilinear; refine 16×
    np.testing.assert_allclose(np.asarray(t.cf(jnp.asarray(W))), ref, atol=2e-5)
    # cloud-in-cell deposition keeps the sample mean exactly; E[m] = i ∂S/∂W at W = 0
    mean_x = 1j * (complex(t.cf(jnp.array([1e-6, 0.0]))) - complex(t.cf(jnp.array([-1e-6, 0.0])))) / 2e-6
    assert abs(mean_x.real - samples[:, 0].mean()) < 1e-6


def _tent_sum_quadrature(f, xb, yb, gl_nodes=16):
    """∫∫ f(m) d²m over ``[xb₀, xb₋₁] × [yb₀, yb₋₁]``, independently of the library's formulas:
    SciPy's adaptive ``quad_vec`` in m_x with the node lines ``xb`` as break points, and
    Gauss–Legendre on each cell ``[yb_j, yb_j+1]`` in m_y (exact for a tent sum's piecewise-linear
    m_y dependence; ``gl_nodes`` points resolve the oscillation of ``e^{−iW·m}``).
    ``f`` maps slopes (n, 2) to values (n,) or (n, k)."""
    t, w = np.polynomial.legendre.leggauss(gl_nodes)
    lo, hi = yb[:-1, None], yb[1:, None]
    y = ((hi - lo) / 2 * t + (hi + lo) / 2).ravel()
    wy = ((hi - lo) / 2 * w).ravel()

    def column(x):
        values = np.asarray(f(np.stack([np.full_like(y, x), y], axis=-1)))
        return np.tensordot(wy, values, axes=(0, 0))

    value, error = si.quad_vec(column, xb[0], xb[-1], points=xb[1:-1], epsabs=1e-14, epsrel=1e-13)
    assert np.all(np.abs(error) < 1e-11)
    return value


def _bordered_node_lines(values, extent, center):
    """Node coordinates of the table bordered by a ring of zero nodes: (x lines, y lines, spacing)."""
    ny, nx = np.shape(values)
    e, c = (
        np.broadcast_to(np.asarray(extent, float), (2,)),
        np.zeros(2) if center is None else np.asarray(center, float),
    )
    h = np.array([2 * e[0] / (nx - 1), 2 * e[1] / (ny - 1)])
    xb = c[0] + np.linspace(-e[0] - h[0], e[0] + h[0], nx + 2)
    yb = c[1] + np.linspace(-e[1] - h[1], e[1] + h[1], ny + 2)
    return xb, yb, h


_density_of = eqx.filter_jit(lambda dist, m: dist.density(m))


def test_tabulated_is_one_sum_of_tents_whose_density_integrates_to_its_cf():
    """A table with a non-zero border (random positive values, 7 × 10 nodes, extent pair, centre)
    means one thing: tents on the nodes, i.e. bilinear between nodes and falling to zero over one
    spacing beyond the outermost (a zero-padded grid). Its density is that interpolant, written
    here independently with SciPy, integrates to 1, and its quadrature transform is cf(W)."""
    import scipy.interpolate

    rng = np.random.default_rng(7)
    V = rng.uniform(0.2, 1.0, (7, 10))
    extent, center = np.array([0.3, 0.5]), np.array([0.05, -0.1])
    t = stats.Tabulated(V, extent=extent, center=center)
    xb, yb, h = _bordered_node_lines(V, extent, center)
    np.testing.assert_allclose(np.asarray(t.spacing), h, rtol=1e-15)
    reference = scipy.interpolate.RegularGridInterpolator(
        (yb, xb), np.pad(V, 1) / (h[0] * h[1] * V.sum()), method="linear", bounds_error=False, fill_value=0.0
    )
    R = float(t.support_radius(1e-6))
    assert R == pytest.approx(np.hypot(*(extent + h)) + np.hypot(*center), rel=1e-14)
    phi = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    m = np.concatenate(
        [
            center + rng.uniform(-1.3, 1.3, (4000, 2)) * (extent + h),  # inside, in the ring and beyond
            [center + extent + 0.5 * h],  # half a spacing beyond the corner node: a quarter of its value
            center + (extent + h) * np.array([[1, 1], [-1, 1], [1, -1], [-1, -1]]) * 1.0001,  # beyond the ring
            R * (1 + 1e-9) * np.stack([np.cos(phi), np.sin(phi)], -1),  # beyond the support radius
        ]
    )
    ours = np.asarray(_density_of(t, jnp.asarray(m)))
    np.testing.assert_allclose(ours, reference(m[:, ::-1]), rtol=1e-12, atol=1e-13)
    assert ours[4000] == pytest.approx(np.asarray(t.values)[-1, -1] / 4, rel=1e-12) and ours[4000] > 0
    assert np.all(ours[4001:] == 0)
    # mass 1, and the transform by quadrature of s(m) e^{−iW·m} is cf(W)
    assert _tent_sum_quadrature(lambda m: _density_of(t, jnp.asarray(m)), xb, yb) == pytest.approx(1.0, abs=1e-12)
    W = np.array([[0.0, 0.0], [7.0, -3.0], [-20.0, 15.0], [35.0, 28.0]])
    quad = _tent_sum_quadrature(
        lambda m: np.asarray(_density_of(t, jnp.asarray(m)))[:, None] * np.exp(-1j * m @ W.T), xb, yb, gl_nodes=24
    )
    np.testing.assert_allclose(np.asarray(t.cf(jnp.asarray(W))), quad, rtol=0, atol=1e-10)
    # a shift keeps the one meaning (cf_grid is checked against cf in test_cf_grid_equals_cf_at_the_nodes)
    moved = np.asarray(_density_of(t.shifted([0.02, 0.03]), jnp.asarray(m + [0.02, 0.03])))
    np.testing.assert_allclose(moved, ours, rtol=1e-12, atol=1e-13)


def test_tabulated_lobe_amplitude_is_the_integral_of_the_lobe():
    """lobes.Tabulated takes the values as the lobe A·g itself: A = h_x h_y Σ values is exactly
    the integral of the lobe (the tent sum on the nodes), for a border that is not zero."""
    rng = np.random.default_rng(11)
    V = 3.7 * rng.uniform(0.1, 1.0, (6, 9))
    extent, center = [0.4, 0.25], [-0.03, 0.08]
    lobe = bs.lobes.Tabulated(V, extent=extent, center=center)
    xb, yb, h = _bordered_node_lines(V, extent, center)
    integral = _tent_sum_quadrature(lambda m: _density_of(lobe, jnp.asarray(m)), xb, yb)
    assert float(lobe.amplitude) == pytest.approx(h[0] * h[1] * V.sum(), rel=1e-14)
    assert float(lobe.amplitude) == pytest.approx(integral, rel=1e-12)
    assert integral == pytest.approx(float(np.real(lobe.cf(jnp.zeros(2)))), rel=1e-12)


def test_tabulated_ones_integrate_to_one_not_to_the_grid_fraction():
    """The issue's example: V = ones((5, 5)), extent 1. cf(0) = 1, and the density integrates to 1
    (the interpolant cut at the grid, as it once was, integrated to 0.64); the lobe of the same
    values has amplitude h² Σ V = 0.5² · 25 = 6.25, its integral."""
    V = np.ones((5, 5))
    t = stats.Tabulated(V, extent=1.0)
    lobe = bs.lobes.Tabulated(V, extent=1.0)
    xb, yb, _ = _bordered_node_lines(V, 1.0, None)
    assert complex(t.cf(jnp.zeros(2))) == pytest.approx(1.0, abs=1e-15)
    mass = _tent_sum_quadrature(lambda m: _density_of(t, jnp.asarray(m)), xb, yb)
    assert mass == pytest.approx(1.0, abs=1e-12)
    inner = np.array([-1.0, 1.0])
    assert _tent_sum_quadrature(lambda m: _density_of(t, jnp.asarray(m)), inner, inner) == pytest.approx(
        0.64, abs=1e-12
    )
    assert float(lobe.amplitude) == 6.25
    lobe_integral = _tent_sum_quadrature(lambda m: _density_of(lobe, jnp.asarray(m)), xb, yb)
    assert lobe_integral == pytest.approx(6.25, rel=1e-12)
    # inside the grid the density is 1/6.25; half of that half a spacing beyond; zero one spacing beyond
    np.testing.assert_allclose(
        np.asarray(_density_of(t, jnp.array([[0.3, -0.7], [1.25, 0.0], [1.25, 1.25], [1.5, 0.2], [0.0, -1.6]]))),
        [0.16, 0.08, 0.04, 0.0, 0.0],
        atol=1e-15,
    )
    assert float(t.support_radius(1e-6)) == pytest.approx(1.5 * math.sqrt(2), rel=1e-15)


def test_from_histogram_is_from_samples_and_checks_its_input():
    rng = np.random.default_rng(2)
    samples = rng.normal(size=(5000, 2)) * 0.1
    hist = stats.SlopeHistogram(0.5, 33)
    hist.add(samples[:, 0] - 0.01, samples[:, 1] + 0.02)
    ours = stats.Tabulated.from_histogram(hist, center=[0.01, -0.02])
    direct = stats.Tabulated.from_samples(samples, extent=0.5, bins=33, center=[0.01, -0.02])
    np.testing.assert_allclose(np.asarray(ours.values), np.asarray(direct.values), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(np.asarray(ours.center), [0.01, -0.02])
    assert not hasattr(stats.SlopeHistogram, "tabulated")
    with pytest.raises(bs.InvalidInputError, match="no sample fell inside"):
        stats.Tabulated.from_histogram(stats.SlopeHistogram(0.5, 9))


@pytest.mark.wrong_types
def test_from_histogram_refuses_what_is_no_histogram():
    with pytest.raises(bs.InvalidInputError, match="hist must be a brdfscale.stats.SlopeHistogram"):
        stats.Tabulated.from_histogram(np.ones((3, 3)))


_STATS_DIR = __import__("pathlib").Path(bs.__file__).parent / "stats"


def _stats_imports(source: str) -> set[str]:
    """The modules of brdfscale/stats (file stems, ``__init__`` for the package) that ``source``,
    a module of that package, imports anywhere — at the top or lazily inside a function."""
    import ast

    siblings = {p.stem for p in _STATS_DIR.glob("*.py")}
    found = set()

    def target(dotted: str | None, names):
        # ``dotted`` is relative to brdfscale.stats: None for the package itself
        if dotted is None:
            found.update(n if n in siblings else "__init__" for n in names)
        else:
            found.add(dotted.split(".")[0] if dotted.split(".")[0] in siblings else "__init__")

    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            names = [a.name for a in node.names]
            module = node.module or ""
            if node.level == 1:
                target(module or None, names)
            elif node.level == 2 and (module == "stats" or module.startswith("stats.")):
                target(module[len("stats.") :] or None, names)
            elif node.level == 2 and not module and "stats" in names:
                found.add("__init__")
            elif node.level == 0 and (module == "brdfscale.stats" or module.startswith("brdfscale.stats.")):
                target(module[len("brdfscale.stats.") :] or None, names)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "brdfscale.stats" or alias.name.startswith("brdfscale.stats."):
                    target(alias.name[len("brdfscale.stats.") :] or None, [])
    return found


def test_no_module_of_stats_imports_one_that_imports_it_back():
    """The import graph of brdfscale/stats, read from the sources with ast (lazy imports inside
    functions included), has no cycle: _histogram once imported _tabulated, which imported
    _histogram back inside from_samples. The package __init__ imports every module, so a module
    importing the package is a cycle too."""
    # the reader sees lazy imports and relative forms
    assert _stats_imports("def f():\n    from ._histogram import SlopeHistogram\n") == {"_histogram"}
    assert _stats_imports("from . import _grid\nfrom ..stats import Delta\n") == {"_grid", "__init__"}
    graph = {p.stem: _stats_imports(p.read_text()) - {p.stem} for p in sorted(_STATS_DIR.glob("*.py"))}
    assert graph["__init__"] >= set(graph) - {"__init__"}  # the check below covers every module
    for a, imported in graph.items():
        for b in imported:
            assert a not in graph[b], f"brdfscale/stats/{a}.py imports {b}, which imports {a} back"
    state = {}

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            assert state.get(nxt) != "open", "import cycle in brdfscale/stats: " + " → ".join(path + [nxt])
            if nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])


@pytest.mark.slow  # a fresh interpreter per module: the default suite's 6-minute budget
def test_each_stats_module_imports_alone_in_a_fresh_interpreter():
    """Every module of brdfscale/stats imports by itself: in a fresh interpreter, with the
    package __init__ files not run at all (stub packages) and every brdfscale module dropped
    from sys.modules before each import (third-party modules stay loaded, so jax is imported
    once), each module loads only what it imports itself and cannot lean on the order in which
    the package imports its modules. The two that once imported each other also import plainly,
    ``python -c "import brdfscale.stats._histogram"``, in a second interpreter."""
    import json
    import os
    import subprocess
    import sys

    root = _STATS_DIR.parent
    modules = [f"brdfscale.stats.{p.stem}" for p in sorted(_STATS_DIR.glob("*.py")) if p.stem != "__init__"]
    alone = (
        "import importlib, json, sys, traceback, types\n"
        "result = {}\n"
        f"for module in {modules!r}:\n"
        "    for name in [m for m in sys.modules if m == 'brdfscale' or m.startswith('brdfscale.')]:\n"
        "        del sys.modules[name]\n"
        f"    for name, path in (('brdfscale', {str(root)!r}), ('brdfscale.stats', {str(_STATS_DIR)!r})):\n"
        "        package = types.ModuleType(name); package.__path__ = [path]; sys.modules[name] = package\n"
        "    try:\n"
        "        importlib.import_module(module)\n"
        "        result[module] = sorted(m for m in sys.modules if m.startswith('brdfscale.stats.'))\n"
        "    except Exception:\n"
        "        result[module] = 'failed: ' + traceback.format_exc().strip().splitlines()[-1]\n"
        "print(json.dumps(result))\n"
    )
    env = dict(
        os.environ,
        JAX_PLATFORMS="cpu",
        PYTHONPATH=os.pathsep.join([str(root.parent), os.environ.get("PYTHONPATH", "")]),
    )
    run = lambda code: subprocess.Popen(
        [sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    first, plain = run(alone), run("import brdfscale.stats._histogram, brdfscale.stats._tabulated")
    out, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    loaded = json.loads(out.strip().splitlines()[-1])
    assert sorted(loaded) == modules
    failures = {m: r for m, r in loaded.items() if isinstance(r, str)}
    assert not failures, failures
    # alone, the histogram needs no table (the conversion is Tabulated.from_histogram)
    assert "brdfscale.stats._tabulated" not in loaded["brdfscale.stats._histogram"]
    assert "brdfscale.stats._histogram" in loaded["brdfscale.stats._tabulated"]
    _, err = plain.communicate(timeout=300)
    assert plain.returncode == 0, err


def test_mixture_is_weighted_sum_and_shift():
    a, b = stats.GGX(0.1), stats.Disk(0.2)
    mix = stats.Mixture([2.0, 6.0], [a, b])
    W = jnp.array([[3.0, 1.0], [0.0, 20.0]])
    np.testing.assert_allclose(mix.cf(W), 0.25 * a.cf(W) + 0.75 * b.cf(W), atol=1e-15)
    shifted = mix.shifted(jnp.array([0.1, 0.0]))
    np.testing.assert_allclose(shifted.cf(W), mix.cf(W) * np.exp(-1j * np.asarray(W)[:, 0] * 0.1), atol=1e-15)
    assert not shifted.isotropic and mix.isotropic


def test_gaussian_surface_closed_form_with_gaussian_window():
    """Gaussian spectrum + Gaussian window (σ_w = μ/√12): Σ = 2σ²ℓ²/(ℓ² + 4σ_w²)² per axis."""
    sigma_h, ell = 0.5, 3.0
    law = stats.GaussianSurface(stats.GaussianCorrelation(sigma_h, ell), window="gaussian")
    for mu in [1e-3, 1.0, 10.0, 100.0]:
        sw2 = mu**2 / 12
        expected = 2 * sigma_h**2 * ell**2 / (ell**2 + 4 * sw2) ** 2
        cov = np.asarray(law.slope_covariance(mu))
        np.testing.assert_allclose(np.diag(cov), expected, rtol=1e-12)
        assert abs(cov[0, 1]) < 1e-15 * expected


@pytest.mark.parametrize("mu", [0.3, 4.0, 50.0])
def test_gaussian_surface_box_window_against_scipy(mu):
    """Box window, anisotropic Gaussian spectrum: separable, so Σ_xx is a product of 1D
    integrals, here by SciPy's adaptive quadrature (the library uses their closed form)."""
    sigma_h, lx, ly = 0.5, 2.0, 5.0
    law = stats.GaussianSurface(stats.GaussianCorrelation(sigma_h, [lx, ly]), window="box")
    cov = np.asarray(law.slope_covariance(mu))

    def one_d(ell, power):
        f = lambda k: (
            k**power * math.sqrt(math.pi) * ell * math.exp(-((k * ell) ** 2) / 4) * np.sinc(k * mu / 2 / math.pi) ** 2
        )
        return 2 * si.quad(f, 0, 40 / ell, limit=2000, epsabs=1e-15, epsrel=1e-13)[0] / (2 * math.pi)

    ref_xx = sigma_h**2 * one_d(lx, 2) * one_d(ly, 0)
    ref_yy = sigma_h**2 * one_d(lx, 0) * one_d(ly, 2)
    np.testing.assert_allclose([cov[0, 0], cov[1, 1]], [ref_xx, ref_yy], rtol=1e-9)
    assert cov[0, 1] == 0.0


@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_gaussian_surface_quadrature_agrees_with_its_closed_form(window):
    """The polar quadrature that serves spectra without a closed form (KCorrelation),
    checked where both exist; μ up to 4ℓ (beyond, the box window's sinc² oscillates faster
    than 1024 log-k nodes resolve, and the closed form is the accurate one)."""
    law = stats.GaussianSurface(stats.GaussianCorrelation(0.5, [2.0, 5.0]), window=window, n_k=1024, n_phi=64)
    for mu in [1e-3, 0.5, 8.0]:
        closed = np.asarray(law.slope_covariance(mu))
        np.testing.assert_allclose(
            np.asarray(law._quadrature_covariance(jnp.asarray(mu))), closed, rtol=5e-14, atol=1e-16
        )


@pytest.mark.parametrize("window", ["box", "gaussian"])
def test_gaussian_surface_closed_form_against_mpmath(window):
    """Σ(μ) of the isotropic Gaussian-correlated surface (closed form) against mpmath's
    quadrature of the factorised 1D integrals; limits μ → 0 (2σ_h²/ℓ²) and derivatives; the
    law gives isotropic Gaussians."""
    import mpmath as mp

    sigma_h, ell = 0.05, 1.5
    surface = stats.GaussianSurface(stats.GaussianCorrelation(sigma_h, ell), window=window)
    slope_variance = lambda mu: surface.slope_covariance(mu)[0, 0]  # noqa: E731
    assert surface.at(1.0).isotropic

    def reference(mu):  # Σ_xx = π ℓ² σ_h² / (2π)² · ∫ k² e^{−ℓ²k²/4} w(k) dk · ∫ e^{−ℓ²k²/4} w(k) dk
        if window == "box":
            w = lambda k: mp.sinc(k * mu / 2) ** 2  # noqa: E731
        else:
            w = lambda k: mp.exp(-(k**2) * mu**2 / 12)  # noqa: E731
        g = lambda k: mp.exp(-(ell**2) * k**2 / 4) * w(k)  # noqa: E731
        inf = [-mp.inf, 0, mp.inf] if window == "gaussian" else mp.linspace(-40, 40, 81)
        i2, i0 = mp.quad(lambda k: k**2 * g(k), inf), mp.quad(g, inf)
        return float(mp.pi * ell**2 * sigma_h**2 / (2 * mp.pi) ** 2 * i2 * i0)

    with mp.workdps(30):
        for mu in (0.01, 1.5, 50.0):
            np.testing.assert_allclose(slope_variance(mu), reference(mu), rtol=1e-12)
    np.testing.assert_allclose(slope_variance(1e-9), 2 * sigma_h**2 / ell**2, rtol=1e-12)
    fd = (slope_variance(1.5 + 1e-6) - slope_variance(1.5 - 1e-6)) / 2e-6
    np.testing.assert_allclose(jax.grad(slope_variance)(1.5), fd, rtol=1e-7)


def test_kcorrelation_gaussian_window_against_scipy():
    A, B, C, mu = 2.0, 1.5, 3.2, 0.7
    spec = stats.KCorrelation(A, B, C)
    cov = np.asarray(stats.GaussianSurface(spec, window="gaussian").slope_covariance(mu))
    f = lambda k: k**3 * A / (1 + (B * k) ** 2) ** (C / 2) * math.exp(-(k**2) * mu**2 / 12)
    ref = si.quad(f, 0, float(spec.k_max), limit=400, epsrel=1e-12)[0] * math.pi / (2 * math.pi) ** 2
    np.testing.assert_allclose(cov[0, 0], ref, rtol=1e-9)


def test_scale_laws_tend_to_delta_and_are_differentiable():
    law = stats.ScaledFamily(stats.GGX, stats.WidthLaw(alpha_max=0.3, mu_c=1.0, exponent=0.8))
    assert float(law.at(1e6).alpha[0]) < 1e-4
    gsurf = stats.GaussianSurface(stats.GaussianCorrelation(0.5, 3.0), window="gaussian")
    assert float(gsurf.slope_covariance(1e4)[0, 0]) < 1e-10
    d = jax.grad(lambda mu: gsurf.slope_covariance(mu)[0, 0])(10.0)
    eps = 1e-5
    fd = (gsurf.slope_covariance(10.0 + eps)[0, 0] - gsurf.slope_covariance(10.0 - eps)[0, 0]) / (2 * eps)
    np.testing.assert_allclose(d, fd, rtol=1e-6)


@pytest.mark.parametrize("make", [lambda a: stats.GGX(a), lambda a: stats.Disk(a), lambda a: stats.Beckmann(a)])
def test_gradients_at_zero_frequency_are_zero_not_nan(make):
    """S(0) = 1 for every width, so ∂S(0)/∂α = 0 (a naive |W| would give NaN)."""
    for W in (jnp.zeros(2), jnp.array([3.0, 0.0])):
        g = jax.grad(lambda a: jnp.real(make(a).cf(W)))(0.2)
        assert np.isfinite(float(g))
    assert float(jax.grad(lambda a: jnp.real(make(a).cf(jnp.zeros(2))))(0.2)) == 0.0


@settings(max_examples=25, deadline=None)
@given(
    ax=st.floats(0.01, 1.0),
    ay=st.floats(0.01, 1.0),
    wx=st.floats(-50, 50),
    wy=st.floats(-50, 50),
)
def test_cf_is_hermitian_and_bounded(ax, ay, wx, wy):
    W = jnp.array([wx, wy])
    for dens in (stats.Beckmann(alpha_x=ax, alpha_y=ay, mean=[0.01, 0.02]), stats.GGX(alpha_x=ax, alpha_y=ay)):
        assert abs(complex(dens.cf(W))) <= 1 + 1e-12
        assert abs(complex(dens.cf(-W)) - np.conj(complex(dens.cf(W)))) < 1e-14


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: stats.Beckmann(-0.1), "alpha must be a positive"),
        (lambda: stats.GGX(0.1, alpha_x=0.2, alpha_y=0.1), "not both"),
        (lambda: stats.Gaussian(cov=[[1.0, 2.0], [2.0, 1.0]]), "positive definite"),
        (lambda: stats.Gaussian(cov=[[1.0, 0.5], [0.0, 1.0]]), "symmetric"),
        (lambda: stats.Mixture([0.5, -0.5], [stats.Delta(), stats.Delta()]), "non-negative"),
        (lambda: stats.Mixture([1.0], [stats.Delta(), stats.Delta()]), "one per component"),
        (lambda: stats.Tabulated(np.ones(5), extent=1.0), "2D array"),
        (lambda: stats.Disk(float("nan")), "finite"),
        (lambda: stats.KCorrelation(1.0, 1.0, 1.5), "C must exceed 2"),
        pytest.param(
            lambda: stats.GaussianSurface(stats.GaussianCorrelation(1.0, 1.0), window="hann"),
            "window must be",
            marks=pytest.mark.wrong_types,
        ),
        (lambda: stats.Delta().density(jnp.zeros(2)), "no pointwise density"),
        (lambda: stats.Beckmann(0.1).density(jnp.zeros(3)), r"shape \(\.\.\., 2\)"),
    ],
)
def test_errors_name_the_problem(make, match):
    with pytest.raises(bs.BrdfscaleError, match=match):
        make()


def _all_families(a, b, c):
    """One density of every family (and a shifted, anisotropic variant where it has one)."""
    rng = np.random.default_rng(int(1e3 * a))
    return [
        stats.Delta(),
        stats.Delta(mean=[c, -a]),
        stats.Beckmann(a),
        stats.Beckmann(alpha_x=a, alpha_y=b, mean=[c, 0.5 * c]),
        stats.Gaussian(cov=[[a * a, 0.3 * a * b], [0.3 * a * b, b * b]], mean=[0.0, c]),
        stats.GGX(a),
        stats.GGX(alpha_x=a, alpha_y=b, mean=[c, c]),
        stats.Disk(b),
        stats.Mixture([0.6, 0.4], [stats.GGX(b), stats.Beckmann(a, mean=[c, 0.0])]),
        stats.Tabulated(rng.random((9, 13)), extent=[a, b]),
        stats.Tabulated(rng.random((9, 13)), extent=[b, a], center=[c, -c]),
    ]


def test_frequency_grid_is_numpys_rfft2_grid():
    n, h = 12, 0.05
    grid = stats.FrequencyGrid(n, 2 * np.pi / (n * h))
    W = np.asarray(grid.nodes())
    np.testing.assert_allclose(
        W[..., 0], np.broadcast_to(2 * np.pi * np.fft.rfftfreq(n, h), (n, n // 2 + 1)), rtol=1e-15
    )
    np.testing.assert_allclose(
        W[..., 1], np.broadcast_to(2 * np.pi * np.fft.fftfreq(n, h)[:, None], (n, n // 2 + 1)), rtol=1e-15
    )


_cf_grid_and_pointwise = eqx.filter_jit(lambda dens, grid: (dens.cf_grid(grid), dens.cf(grid.nodes())))


@settings(max_examples=10, deadline=None)
@given(
    a=st.floats(0.02, 0.5),
    b=st.floats(0.02, 0.5),
    c=st.floats(-0.2, 0.2),
    n=st.sampled_from([7, 16]),
    step=st.floats(0.5, 20.0),
)
@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@example(a=0.5, b=0.5, c=0.0, n=16, step=20.0)  # exp(−3200) · exp(+1920) if factorised
def test_cf_grid_equals_cf_at_the_nodes(a, b, c, n, step):
    """The structured evaluation (separable factors, one value per distinct radius, matmuls
    for tables) is the pointwise transform, for every family, odd and even grids, including
    where per-axis factors of a correlated Gaussian would under- and overflow."""
    grid = stats.FrequencyGrid(n, step)
    for dens in _all_families(a, b, c):
        structured, pointwise = _cf_grid_and_pointwise(dens, grid)
        np.testing.assert_allclose(
            np.asarray(structured), np.asarray(pointwise), rtol=0, atol=2e-14, err_msg=type(dens).__name__
        )


@pytest.mark.slow  # 5–30 s on 2 cores: run in .ci/run's second step, outside the default suite's 6-minute budget
@settings(max_examples=10, deadline=None)
@given(a=st.floats(0.02, 0.5), b=st.floats(0.02, 0.5), c=st.floats(-0.2, 0.2))
def test_cf_radial_is_cf_on_a_ray_for_every_isotropic_family(a, b, c):
    """``cf_radial(k)`` (overridden by GGX and Disk, the default for the rest) equals the real
    part of ``cf`` at ``(k cos φ, k sin φ)`` for every structurally isotropic density, and so
    does its derivative in the width."""
    k = jnp.asarray(np.concatenate([[0.0], np.logspace(-2, 3, 40)]))
    phi = 0.7
    W = jnp.stack([k * np.cos(phi), k * np.sin(phi)], -1)
    isotropic = [d for d in _all_families(a, b, c) if d.isotropic]
    assert {type(d).__name__ for d in isotropic} >= {"GGX", "Disk", "Gaussian", "Delta"}
    for dens in isotropic:
        np.testing.assert_allclose(
            np.asarray(dens.cf_radial(k)),
            np.asarray(jnp.real(dens.cf(W))),
            rtol=1e-13,
            atol=1e-15,
            err_msg=type(dens).__name__,
        )
    for family in (stats.GGX, stats.Disk):
        radial = jax.grad(lambda w: jnp.sum(family(w).cf_radial(k)))(a)
        pointwise = jax.grad(lambda w: jnp.sum(jnp.real(family(w).cf(W))))(a)
        assert float(radial) == pytest.approx(float(pointwise), rel=1e-12), family.__name__


def test_cf_grid_is_differentiable_like_cf():
    grid = stats.FrequencyGrid(16, 3.0)
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(16, 9)))

    def loss(params, structured):
        a, c = params
        dens = stats.Mixture([0.5, 0.5], [stats.GGX(a), stats.Beckmann(a, mean=jnp.stack([c, 0.0]))])
        values = dens.cf_grid(grid) if structured else dens.cf(grid.nodes())
        return jnp.sum(weights * jnp.abs(values) ** 2)

    params = jnp.array([0.2, 0.05])
    gradient = jax.jit(jax.grad(loss), static_argnums=1)
    np.testing.assert_allclose(gradient(params, True), gradient(params, False), rtol=1e-12)


@pytest.mark.parametrize(
    "make, match",
    [
        (
            lambda: stats.GaussianSurface(stats.GaussianCorrelation(1.0, 1.0)).at(jnp.array([1.0, 2.0])),
            "single facet size",
        ),
        pytest.param(
            lambda: stats.GaussianSurface(stats.GaussianCorrelation(1.0, 1.0)).slope_covariance(jnp.array([1.0, 2.0])),
            "single facet size",
            marks=pytest.mark.wrong_types,
        ),
        (lambda: stats.ScaledFamily(stats.GGX, stats.WidthLaw(0.1, 1.0, 1.0)).at(-1.0), "positive facet size"),
        (lambda: stats.ScaledFamily(stats.Disk, stats.WidthLaw(0.1, 1.0, 1.0)), "taking alpha="),
        pytest.param(lambda: stats.ScaledFamily(stats.GGX, None), "law must map", marks=pytest.mark.wrong_types),
        (lambda: stats.GGX(0.1).cf(jnp.array([jnp.nan, 0.0])), "W must be finite"),
        (lambda: stats.Disk(radius=0.1).cf(jnp.array([jnp.inf, 0.0])), "W must be finite"),
        (lambda: stats.Beckmann(0.1).density(jnp.array([0.1, 0.2j])), "m must be real"),
        pytest.param(lambda: stats.FrequencyGrid(4.7, 1.0), "size must be an integer", marks=pytest.mark.wrong_types),
        (lambda: stats.FrequencyGrid(4, -1.0), "step must be a positive"),
        (lambda: stats.FrequencyGrid(4, float("nan")), "step must be finite"),
        (lambda: stats.Beckmann(1e-77), "normal float64"),
        (lambda: stats.Beckmann(1e160), "normal float64"),
        (lambda: stats.Gaussian(cov=1e-300 * jnp.eye(2)), "normal float64"),
        (lambda: stats.GGX("0.1"), "string"),
    ],
    ids=[
        "vector mu",
        "vector mu covariance",
        "negative mu",
        "family without alpha",
        "no law",
        "NaN frequency",
        "infinite frequency",
        "complex slopes",
        "fractional grid size",
        "negative step",
        "NaN step",
        "variance underflows",
        "variance overflows",
        "determinant underflows",
        "string width",
    ],
)
def test_bad_arguments_are_named(make, match):
    """Each of these once returned a value (a wrong one, or a NaN turned finite) or failed deep
    inside; each is now an InvalidInputError that says what was wrong."""
    with pytest.raises(bs.InvalidInputError, match=match):
        make()


def test_integer_frequency_step_gives_real_radii():
    """FrequencyGrid(4, 1): an integer step once truncated the radii to integers."""
    grid = stats.FrequencyGrid(4, 1)
    assert complex(stats.GGX(0.1).cf_grid(grid)[1, 1]) == pytest.approx(
        complex(stats.GGX(0.1).cf(jnp.array([1.0, 1.0]))), rel=1e-14
    )


@pytest.mark.parametrize("scale", [1e-320, 1.0, 1e308])
def test_mixture_weights_normalise_at_any_scale(scale):
    """Subnormal weights (flushed to zero by XLA) and weights whose sum overflows once gave NaN."""
    given = np.array([0.7 * scale, 0.3 * scale])  # as represented (subnormals carry few digits)
    mixture = stats.Mixture(given, [stats.Beckmann(0.1), stats.Beckmann(0.2)])
    np.testing.assert_allclose(np.asarray(mixture.weights), given / given[0] / (1 + given[1] / given[0]), rtol=1e-14)
    assert np.isfinite(float(mixture.density(jnp.zeros(2))))


@pytest.mark.parametrize(
    "call",
    [
        lambda: stats.Tabulated.from_samples(np.array([[0.1, 0.2j]]), extent=0.5),
        lambda: stats.Tabulated.from_samples(np.zeros((4, 2)), extent=0.5, weights=np.ones(3)),
        lambda: stats.Tabulated.from_samples(np.zeros((4, 2)), extent=0.5, weights=np.full(4, np.nan)),
        lambda: stats.Tabulated.from_samples([["a", "b"]], extent=0.5),
        lambda: stats.Tabulated.from_samples(np.zeros((4, 2)), extent=0.5, bins=10**6),
    ],
    ids=["complex samples", "weights per sample", "NaN weights", "text samples", "bins beyond the memory cap"],
)
def test_histogram_input_is_checked_before_binning(call):
    with pytest.raises(bs.InvalidInputError):
        call()
