"""Reference problems of the evolution planner, answered independently of brdfscale's evolution code.

Each problem is a material (a Beckmann lobe at μ0 = 1e-4 whose statistics follow the width law
``WIDTH``) evaluated at a few scales μ and slope offsets u:

* ``closed_form``   — Beckmann statistics: Gaussian variances add (exact, :func:`gaussian_reference`);
* ``beckmann_ggx``  — GGX statistics: Hankel integral by SciPy Gauss–Legendre quadrature with
  SciPy's K₁, J₀ (:func:`hankel_reference`, :func:`_hankel_rows`; against mpmath:
  :func:`mpmath_check`);
* ``skewed_mixture`` — skewed zero-mean two-Gaussian statistics: the 2D inverse Fourier integral
  by a tensor Gauss–Legendre rule in NumPy (:func:`skewed_reference`);
* ``disk``          — a uniform disk of slopes diluted with flat facets: SciPy Hankel quadrature;
* ``plus``          — nearly-specular statistics with the plus-distribution h_0 (A. Pak, "Scale-related
  evolution of BRDFs", §6): SciPy Hankel quadrature with H_0 from its power series (:func:`plus_h0`);
* ``so3``           — an anisotropic Beckmann facet lobe under isotropic rotational diffusion: the
  group integral against the SO(3) heat kernel by a tensor Gauss–Legendre rule in exponential
  coordinates with SciPy's rotations (:func:`so3_reference`).

Used by tests/test_scene.py and by the benchmark experiments/bench_planner.py (which measures
every path's error against them); brdfscale supplies only the materials' objects
(:func:`material`, :func:`so3_material`) and the query geometry.
"""

import math

import jax.numpy as jnp
import numpy as np
import scipy.special as sp

from brdfscale import lobes, plus, scene, so3, stats


LOBE_ALPHA = 0.05
MU0 = 1e-4
WIDTH = stats.WidthLaw(0.2, 1e-3, 0.5)  # α(μ) of the statistics


# -- statistics families for the reference problems -----------------------------------------------
SKEW = (0.7, 0.3)  # weights; means ±: 0.7·d1 + 0.3·d2 = 0


def skewed(alpha):
    """Zero-mean skewed mixture: 70 % Beckmann(α) at +0.3α, 30 % Beckmann(1.5α) at −0.7α (x)."""
    alpha = jnp.asarray(alpha)
    d1 = jnp.stack([0.3 * alpha, 0.0 * alpha])
    d2 = jnp.stack([-0.7 * alpha, 0.0 * alpha])
    return stats.Mixture(jnp.array(SKEW), [stats.Beckmann(alpha, mean=d1), stats.Beckmann(1.5 * alpha, mean=d2)])


def disk_fraction(alpha):
    """f(μ) of the diluted-disk statistics, from the width law: f = (α/α_max)²."""
    return (alpha / WIDTH.alpha_max) ** 2


def diluted_disk(alpha):
    """``f Disk(r) + (1 − f) δ``: a fraction f of facets in pits with slopes uniform in a disk of
    radius r = 0.1, the rest flat; f = (α/α_max)² falls with the scale."""
    f = disk_fraction(jnp.asarray(alpha))
    return stats.Mixture(jnp.stack([f, 1 - f]), [stats.Disk(0.1), stats.Delta()])


PLUS_X0, PLUS_STRENGTH = 0.02, 0.05


def nearly_specular(alpha):
    """``(1 − w) δ + 0.05 w h_0 + w Beckmann(α)`` with w = α/α_max and the plus-distribution
    h_0 of cut-off 0.02 (seed §6): mirror-like at coarse scales, rough and glinting at fine."""
    w = jnp.asarray(alpha) / WIDTH.alpha_max
    return plus.NearlySpecular(
        1 - w, jnp.stack([PLUS_STRENGTH * w]), PLUS_X0, smooth=stats.Beckmann(alpha), smooth_weight=w
    )


def plus_h0(z):
    """``H_0`` at ``z = |W| x0`` by its power series (docs/conventions.md §4), fine in float64 for z ≲ 10."""
    z = np.asarray(z, float)
    k = np.arange(1, 80)[:, None]
    logs = 2 * k * np.log(np.maximum(z, 1e-300) / 2)[None, :] - 2 * sp.gammaln(k + 1)
    terms = (-1.0) ** k * np.exp(logs) / (2 * k)
    return np.where(z > 0, np.sum(terms, axis=0), 0.0)


def material(kind):
    family = {
        "closed_form": stats.Beckmann,
        "beckmann_ggx": stats.GGX,
        "skewed_mixture": skewed,
        "disk": diluted_disk,
        "plus": nearly_specular,
    }[kind]
    return scene.Material(lobes.Beckmann(LOBE_ALPHA), MU0, stats.ScaledFamily(family, WIDTH))


def alpha(mu):
    return float(WIDTH(mu))


# -- independent references --------------------------------------------------------------------------
def _xk1(x):
    """x K₁(x) by SciPy (1 at 0), computed as x k1e(x) e^{−x}."""
    x = np.asarray(x, float)
    safe = np.where(x > 0, x, 1.0)
    return np.where(x > 0, safe * sp.k1e(safe) * np.exp(-safe), 1.0)


def _radial_transform(kind, mu, k):
    a0, a1 = alpha(MU0), alpha(mu)
    lobe = np.exp(-((LOBE_ALPHA * k) ** 2) / 4)
    if kind == "beckmann_ggx":
        # ratio x0 K1(x0) / (x1 K1(x1)) with the exponentials combined (no underflow)
        x0, x1 = a0 * k, a1 * k
        s0 = np.where(x0 > 0, x0 * sp.k1e(np.where(x0 > 0, x0, 1)), 1.0)
        s1 = np.where(x1 > 0, x1 * sp.k1e(np.where(x1 > 0, x1, 1)), 1.0)
        return lobe * s0 / s1 * np.exp(-(x0 - x1))
    if kind == "disk":

        def S(a):
            f = (a / float(WIDTH.alpha_max)) ** 2
            x = 0.1 * k
            jinc = np.where(x > 0, 2 * sp.j1(np.where(x > 0, x, 1)) / np.where(x > 0, x, 1), 1.0)
            return f * jinc + (1 - f)

        return lobe * S(a0) / S(a1)
    if kind == "plus":

        def S(a):
            w = a / float(WIDTH.alpha_max)
            return (1 - w) + PLUS_STRENGTH * w * plus_h0(k * PLUS_X0) + w * np.exp(-((a * k) ** 2) / 4)

        return lobe * S(a0) / S(a1)
    raise ValueError(kind)


def hankel_reference(kind, mu, r, nodes=4096):
    """``g(r) = (2π)⁻¹ ∫ G(k) J₀(kr) k dk`` by Gauss–Legendre on [0, K] (G < 1e-17 beyond K)."""
    K = math.sqrt(4 * math.log(1e17)) / LOBE_ALPHA
    x, w = sp.roots_legendre(nodes)
    k, wk = 0.5 * K * (x + 1), 0.5 * K * w
    G = _radial_transform(kind, mu, k)
    out = []
    for chunk in np.array_split(np.asarray(r, float), max(1, len(r) // 4096)):
        out.append((sp.j0(chunk[:, None] * k[None, :]) @ (wk * k * G)) / (2 * np.pi))
    return np.concatenate(out)


def mpmath_check(kind, mu, r):
    """The same Hankel integral by mpmath (15 digits), for one radius."""
    import mpmath

    a0, a1 = alpha(MU0), alpha(mu)

    def S(a, k):
        if kind == "beckmann_ggx":
            return a * k * mpmath.besselk(1, a * k) if k > 0 else mpmath.mpf(1)
        f = (a / float(WIDTH.alpha_max)) ** 2
        x = 0.1 * k
        return f * (2 * mpmath.besselj(1, x) / x if x > 0 else 1) + (1 - f)

    def G(k):
        return mpmath.exp(-((LOBE_ALPHA * k) ** 2) / 4) * S(a0, k) / S(a1, k)

    K = math.sqrt(4 * math.log(1e17)) / LOBE_ALPHA
    edges = list(np.linspace(0, K, 9))
    return float(mpmath.quad(lambda k: G(k) * mpmath.besselj(0, k * r) * k, edges) / (2 * mpmath.pi))


def gaussian_reference(mu, u):
    """Closed form: Beckmann lobe ∗ Beckmann(μ0) ∗⁻¹ Beckmann(μ) = Gaussian of variance
    (α_l² + α0² − α1²)/2 per axis."""
    var = (LOBE_ALPHA**2 + alpha(MU0) ** 2 - alpha(mu) ** 2) / 2
    return np.exp(-np.sum(u**2, -1) / (2 * var)) / (2 * np.pi * var)


def skewed_reference(mu, u, nodes=600):
    """2D inverse transform of ``G = G_lobe S(μ0)/S(μ)`` by a tensor Gauss–Legendre rule."""

    def S(a, Wx, Wy):
        out = 0
        for w, scale, shift in ((SKEW[0], 1.0, 0.3), (SKEW[1], 1.5, -0.7)):
            out = out + w * np.exp(-((scale * a) ** 2) * (Wx**2 + Wy**2) / 4 - 1j * Wx * shift * a)
        return out

    K = math.sqrt(4 * math.log(1e17)) / LOBE_ALPHA
    x, w = sp.roots_legendre(nodes)
    W, wW = K * x, K * w
    Wx, Wy = np.meshgrid(W, W, indexing="xy")
    G = np.exp(-(LOBE_ALPHA**2) * (Wx**2 + Wy**2) / 4) * S(alpha(MU0), Wx, Wy) / S(alpha(mu), Wx, Wy)
    Gw = G * wW[None, :] * wW[:, None]
    ex = np.exp(1j * u[:, 0, None] * W[None, :])  # (q, nx)
    ey = np.exp(1j * u[:, 1, None] * W[None, :])  # (q, ny)
    return np.real(np.einsum("qy,yx,qx->q", ey, Gw, ex)) / (2 * np.pi) ** 2


# -- SO(3) reference problem --------------------------------------------------------------------------
SO3_ALPHA = (0.3, 0.15)  # the facet lobe's roughness along the facet's tangent and bitangent
SO3_PAIRS = (((0.3, 0.0), (0.4, math.pi)), ((0.5, 0.4), (0.2, 2.5)))  # (polar, azimuth) of i and o


def so3_material(alpha=SO3_ALPHA, D=1.0):
    """Anisotropic Beckmann facet lobe at μ0 with rotational-diffusion statistics (isotropic
    by default: D = 1, τ(μ) = α(μ)²/4 with the problems' width law)."""
    return scene.AnisotropicMaterial(so3.AnisotropicMicrofacetLobe(*alpha), MU0, so3.DiffusionLaw(WIDTH, D))


def _unit(polar, azimuth):
    return np.array([math.sin(polar) * math.cos(azimuth), math.sin(polar) * math.sin(azimuth), math.cos(polar)])


def so3_lobe(i, o, rotations, alpha=SO3_ALPHA):
    """ρ(i, o, Γ) of the anisotropic Beckmann facet lobe in NumPy (seed §2, docs/conventions.md §1): in the
    facet frame ``g(m(h'))/(4 o'_z h'_z⁴)``, zero where i or o is below the facet's horizon."""
    ip = np.einsum("...ji,j->...i", rotations, i)
    op = np.einsum("...ji,j->...i", rotations, o)
    h = ip + op
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    ax, ay = alpha
    m = h[..., :2] / h[..., 2:3]
    g = np.exp(-((m[..., 0] / ax) ** 2) - (m[..., 1] / ay) ** 2) / (np.pi * ax * ay)
    value = g / (4 * op[..., 2] * h[..., 2] ** 4)
    return np.where((ip[..., 2] > 0) & (op[..., 2] > 0), value, 0.0)


def heat_kernel(t, theta):
    """The SO(3) heat kernel (isotropic rotational diffusion for time t, D = 1) at rotation
    angle θ, by its character sum ``Σ_J (2J+1)/(8π²) e^{−tJ(J+1)} sin((2J+1)θ/2)/sin(θ/2)``."""
    J = np.arange(int(math.sqrt(45 / t)) + 2)[:, None]
    theta = np.asarray(theta, float)[None, :]
    half = np.maximum(np.sin(theta / 2), 1e-300)
    chi = np.where(theta > 1e-8, np.sin((2 * J + 1) * theta / 2) / half, 2 * J + 1.0)
    return np.sum((2 * J + 1) / (8 * np.pi**2) * np.exp(-t * J * (J + 1)) * chi, axis=0)


def so3_reference(mu, i, o, angles, nodes=40, alpha=SO3_ALPHA):
    """``ρ_μ(Γ∞) = ∫ ρ_μ0(Γ∞ Δ) k(Δ) dΔ`` with k the heat kernel of time τ(μ0) − τ(μ): the
    evolution ``R(μ) = R(μ0) e^{−(τ0 − τ)J(J+1)}`` as a group integral, by a tensor
    Gauss–Legendre rule in exponential coordinates Δ = exp(ω) (Haar density 4 sin²(|ω|/2)/|ω|²),
    with SciPy's rotations (``Rotation.from_euler('ZYZ')`` for Γ∞ = U(α) A(β) U(γ)). Returns the
    values and the rule's total weight (1 when the kernel is resolved and normalised)."""
    from scipy.spatial.transform import Rotation

    t = float(so3_material().tau(MU0) - so3_material().tau(mu))
    R = math.sqrt(4 * t * 42)
    x, w = sp.roots_legendre(nodes)
    X, Y, Z = np.meshgrid(R * x, R * x, R * x, indexing="ij")
    omega = np.stack([X.ravel(), Y.ravel(), Z.ravel()], -1)
    theta = np.linalg.norm(omega, axis=-1)
    haar = np.where(theta > 0, 4 * np.sin(theta / 2) ** 2 / np.maximum(theta, 1e-300) ** 2, 1.0)
    weight = (R**3 * (w[:, None, None] * w[None, :, None] * w[None, None, :]).ravel()) * heat_kernel(t, theta) * haar
    delta = Rotation.from_rotvec(omega).as_matrix()
    out = []
    for a in np.atleast_2d(angles):
        gamma = Rotation.from_euler("ZYZ", a).as_matrix()
        out.append(np.sum(weight * so3_lobe(i, o, gamma @ delta, alpha)))
    return np.array(out), float(np.sum(weight))


def so3_problem(mus, n, nodes=48):
    """Queries: for each (i, o) pair, global orientations whose normal slope lies on a spiral of
    radius ≤ 0.25 around the half vector's slope, with twists spread over [0, π)."""
    i_all, o_all, m_all, twist_all, mu_all, ref, peak = [], [], [], [], [], [], []
    pairs, pair_angles = [], []
    r = np.linspace(0, 0.25, n)
    phi = 7.3 * np.linspace(0, 2 * np.pi, n, endpoint=False)
    twist = np.pi * ((np.arange(n) * 0.618034) % 1.0)
    for (ti, pi_), (to, po) in SO3_PAIRS:
        i, o = _unit(ti, pi_), _unit(to, po)
        h = (i + o) / np.linalg.norm(i + o)
        m = h[:2] / h[2] + np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
        q = scene.Queries(np.tile(i, (n, 1)), np.tile(o, (n, 1)), np.ones(n), m_inf=m, twist=twist)
        angles = np.asarray(q.euler_angles())
        pairs.append((i, o))
        pair_angles.append(angles)
        for mu in mus:
            values, _ = so3_reference(mu, i, o, angles, nodes)
            i_all.append(np.tile(i, (n, 1)))
            o_all.append(np.tile(o, (n, 1)))
            m_all.append(m)
            twist_all.append(twist)
            mu_all.append(np.full(n, mu))
            ref.append(values)
            peak.append(np.full(n, np.max(np.abs(values))))
    cat = np.concatenate
    queries = scene.Queries(cat(i_all), cat(o_all), cat(mu_all), m_inf=cat(m_all), twist=cat(twist_all))
    return queries, cat(ref), cat(peak), {"pairs": pairs, "angles": pair_angles, "mus": mus}


def reference(kind, mu, u):
    if kind == "closed_form":
        return gaussian_reference(mu, u)
    if kind == "skewed_mixture":
        return skewed_reference(mu, u)
    return hankel_reference(kind, mu, np.linalg.norm(u, axis=-1))


def _hankel_rows(mu, r, nodes=2048):
    """GGX problem's Hankel integral, one scale per row (SciPy)."""
    K = math.sqrt(4 * math.log(1e17)) / LOBE_ALPHA
    x, w = sp.roots_legendre(nodes)
    k, wk = 0.5 * K * (x + 1), 0.5 * K * w
    a0, a1 = alpha(MU0), np.asarray(WIDTH(mu))[:, None]
    x0, x1 = a0 * k[None, :], a1 * k[None, :]
    G = np.exp(-((LOBE_ALPHA * k) ** 2) / 4) * x0 * sp.k1e(x0) / (x1 * sp.k1e(x1)) * np.exp(-(x0 - x1))
    return np.sum(G * (wk * k) * sp.j0(r[:, None] * k[None, :]), axis=1) / (2 * np.pi)
