"""The Mitsuba 3 BSDF ``"brdfscale"``: an evolved, masked lobe read from tables (issue 33 item 1).

Convention (docs/conventions.md §1, Mitsuba's local frame, z the macroscopic normal). Mitsuba's ``si.wi`` points
towards where the path came from — the detector, brdfscale's ``o`` — and ``wo`` towards the light, brdfscale's
``i``. ``eval`` returns ``f · cosθ_wo``, which with ``ρ = β cosθ_i`` (the seed absorbs the cosine) is the
project's ρ itself::

    eval(wi, wo) = ρ(i = wo, o = wi) = A g_μ(m_s) / (4 cosθ_wi cos⁴θ_h) · G₂(wi, wo),

``m_s`` the slope of ``h = (wi + wo)/|wi + wo|``, ``A g_μ`` the lobe table at the interaction's scale μ (bilinear
in the offset — the tent sum of :class:`brdfscale.stats.Tabulated`, bordered by zero nodes — and linear in ln μ
between the ladder's scales, clamped to its ends), ``G₂`` Smith's masking–shadowing of :mod:`._masking` or 1.
``f = eval/cosθ_wo`` is symmetric in wi and wo (reciprocity).

Sampling: a slope ``m`` is drawn from the lobe at μ — Mitsuba's ``MarginalContinuous2D1``, the piecewise-bilinear
density on the same zero-bordered grid, normalised per scale and mixed linearly in ln μ (its density is exactly
that mixture: tests/test_render.py) — then ``h = (m, 1)/|(m, 1)|`` and ``wo`` the mirror image of ``wi`` about h.
Its solid-angle density, with ``d²m = dω_h / cos³θ_h`` (docs/conventions.md §1) and ``dω_h = dω_o / (4 wi·h)``::

    pdf(wo) = p_m(m_s) / (cos³θ_h · 4 wi·h).

Any lobe shape is sampled exactly so — anisotropic and off-centre ones included. Masking is not sampled (the weight
``eval/pdf`` carries it). The lobe's scale μ: a fixed ``mu``, or the footprint of the interaction,
``√|dp/dx × dp/dy| / texel`` from the uv partials that :mod:`._integrator` fills (``si.compute_uv_partials``).
"""

import math

import numpy as np

from .._errors import InvalidInputError
from ..exr import read_lobe_table
from ._masking import g1_table, table_shapes
from ._material import scalar_table, SPLINE_PAD
from ._spline import extend, GHOSTS, PERIODIC_PAD, runs, runs_coefficients
from ._variants import per_variant


PLUGIN = "brdfscale"
"""The name the BSDF is registered under (:func:`brdfscale.render.register`)."""


class Host:
    """What the plugin renders, host-side, whatever the lobe's form: the ladder ``ln μ_k``, a fixed scale or None
    (the footprint), the texel, the masking choice (None: no masking)."""

    def __init__(self, scales, masking, *, mu=None, texel=1.0):
        scales = np.asarray(scales, float)
        if len(scales) == 1:  # one scale: a constant ladder of two equal planes keeps one code path
            scales = np.array([scales[0], scales[0] * math.e])
        self.log_mu = [float(x) for x in np.log(scales)]
        self.masking = masking
        self.mu = None if mu is None else float(mu)
        self.texel = float(texel)

    form: str = ""
    """``"table"``, ``"spline"`` or ``"closed"`` (the subclass's)."""

    def renderer(self, mi):
        """The Dr.Jit evaluator of this form for ``mi``'s variant."""
        raise NotImplementedError

    @staticmethod
    def doubled(values: np.ndarray) -> np.ndarray:
        """Per-scale values with a one-scale ladder repeated (the constant ladder of :class:`Host`)."""
        return np.concatenate([values, values]) if len(values) == 1 else values


class Tables(Host):
    """A tabulated lobe: the padded lobe values (L, N, N) and the G₁ tables of :mod:`._masking`.

    ``shapes``: the lobe shapes whose Smith Λ makes the masking tables (default the table's own, tabulated).
    """

    form = "table"
    pad: int = 1
    """The rings of zero nodes around the lobe values (the table form's one: the tent sum's zero ring)."""

    def __init__(self, table, masking, *, mu=None, texel=1.0, shapes=None):
        super().__init__(table.scales, masking, mu=mu, texel=texel)
        values = scalar_table(table)
        n = values.shape[1]
        h = 2 * table.extent / (n - 1)
        pad = ((0, 0), (self.pad, self.pad), (self.pad, self.pad))
        self.values = self.doubled(np.pad(values, pad))  # (L, N, N) with the zero rings
        self.half = float(table.extent + self.pad * h)  # the padded grid spans [−half, half]²
        self.g1 = None
        if masking is not None:
            self.g1 = self.doubled(g1_table(table_shapes(table) if shapes is None else shapes))  # (L, n_s, n_phi)

    def renderer(self, mi):
        return _TableLobe(mi, self)


class Splines(Tables):
    """A tabulated lobe rendered by tricubic B-splines (:mod:`._spline`): the lobe values bordered by
    :data:`._material.SPLINE_PAD` rings of zero nodes (L, N, N) — what the sampler draws from, as the table form's
    — and, run by run of the ladder (``breaks``: the table's ``metadata["spline_breaks"]`` where
    :func:`brdfscale.render.bsdf` wrote them, else its runs of equal ln-μ steps), the B-spline coefficients of the
    values and of the G₁ tables of :mod:`._masking` (ghost nodes beyond the ends of ln μ and s, periodic in φ).

    ``shapes``: the lobe shapes whose Smith Λ makes the masking tables (default the table's own, tabulated).
    """

    form = "spline"
    pad = SPLINE_PAD

    def __init__(self, table, masking, *, mu=None, texel=1.0, shapes=None):
        super().__init__(table, masking, mu=mu, texel=texel, shapes=shapes)  # the padded values and G₁ tables
        count = len(self.log_mu)
        breaks = table.metadata.get("spline_breaks") if len(table.scales) > 1 else None
        if breaks is None:
            breaks = runs(self.log_mu)
        ok = isinstance(breaks, (list, tuple)) and len(breaks) >= 2 and all(isinstance(k, int) for k in breaks)
        breaks = list(breaks) if ok else [0]
        if not ok or breaks[0] != 0 or breaks[-1] != count - 1 or any(q <= p for p, q in zip(breaks, breaks[1:])):
            raise InvalidInputError(
                f"the table's metadata spline_breaks must be increasing level indices from 0 to {count - 1}; got "
                f"{breaks!r} — drop the key to split the ladder into its runs of equal ln-μ steps."
            )
        steps = np.diff(self.log_mu)
        for p, q in zip(breaks, breaks[1:]):
            if np.ptp(steps[p:q]) > 1e-6 * steps[p:q].mean():
                raise InvalidInputError(
                    f"the spline form needs equal ln-μ steps between breaks; levels {p}…{q} of this table are not — "
                    "drop spline_breaks from its metadata or render it with form='table'."
                )
        self.breaks = [int(k) for k in breaks]
        self.coefficients = runs_coefficients(self.values, self.breaks)
        if self.g1 is not None:
            g1 = self.g1[..., :-1]  # φ = 2π is φ = 0
            self.g1 = runs_coefficients(extend(g1, axis=1), self.breaks, periodic=(2,), extrapolated=(1,))
        offset, self.runs = 0, []
        for p, q in zip(self.breaks, self.breaks[1:]):  # (ln μ at its start, step, nodes, first coefficient index)
            self.runs.append((self.log_mu[p], (self.log_mu[q] - self.log_mu[p]) / (q - p), q - p + 1, offset))
            offset += q - p + 1 + 2 * GHOSTS

    def renderer(self, mi):
        return _SplineLobe(mi, self)


class Gaussians(Host):
    """Gaussian lobes in closed form: per scale ``[A, c_x, c_y, Σ_xx, Σ_xy, Σ_yy]`` (L, 6)
    (:func:`._material.gaussian_parameters`), interpolated linearly in ln μ; density and Smith Λ evaluated exactly."""

    form = "closed"

    def __init__(self, scales, parameters, masking, *, mu=None, texel=1.0):
        super().__init__(scales, masking, mu=mu, texel=texel)
        self.parameters = self.doubled(np.asarray(parameters, float))

    def renderer(self, mi):
        return _GaussianLobe(mi, self)


def dr_jit(mi) -> bool:
    """Whether ``mi``'s variant is a JIT (vectorised) one, not scalar."""
    import drjit as dr

    return bool(dr.is_jit_v(mi.Float))


def ladder_index(dr, mi, x, log_mu):
    """The continuous ladder index ``j(ln μ)``: k + f between scales k and k + 1 (piecewise linear, clamped)."""
    j = mi.Float(0.0)
    for a, b in zip(x[:-1], x[1:]):
        j += dr.clip((log_mu - a) / (b - a), 0.0, 1.0)
    return j


class _TableLobe:
    """The tabulated lobe in Dr.Jit (module docstring): a 3-D texture (offset × ladder), Mitsuba's
    ``MarginalContinuous2D1`` sampler, G₁ textures."""

    key = "table"

    def __init__(self, mi, host: "Tables | Splines", texels=None):
        """``texels``: what the lobe texture holds (default the host's values; the spline form's coefficients)."""
        self.mi, self.host = mi, host
        L, N, _ = host.values.shape
        self.levels, self.nodes = L, N
        texels = host.values if texels is None else texels
        self.table = mi.TensorXf(np.ascontiguousarray(texels[..., None], dtype=np.float32))
        self.tex = mi.Texture3f(self.table)
        self.sampler = mi.MarginalContinuous2D1(
            np.ascontiguousarray(np.maximum(host.values, 0.0), dtype=np.float32), [host.log_mu]
        )
        self.g1 = None
        if host.g1 is not None:
            self.g1 = mi.Texture3f(mi.TensorXf(np.ascontiguousarray(host.g1[..., None], dtype=np.float32)))

    def at(self, log_mu):
        """The level: the texture coordinate along the ladder (texel-centred) and ln μ (for the sampler)."""
        import drjit as dr

        return (ladder_index(dr, self.mi, self.host.log_mu, log_mu) + 0.5) / self.levels, log_mu

    def value(self, m, level):
        import drjit as dr

        mi, n, half = self.mi, self.nodes, self.host.half
        px = ((m.x + half) / (2 * half) * (n - 1) + 0.5) / n
        py = ((m.y + half) / (2 * half) * (n - 1) + 0.5) / n
        inside = (dr.abs(m.x) < half) & (dr.abs(m.y) < half)
        # an evolved lobe may dip below 0 (regularisation ringing, a spline's tails): shaded as 0, as it is sampled
        return dr.select(inside, dr.maximum(self._fetch(self.tex, mi.Point3f(px, py, level[0])), 0.0), 0.0)

    @staticmethod
    def _fetch(texture, point):
        """The texture's value at ``point``: bilinear (trilinear with the ladder)."""
        return texture.eval(point)[0]

    def _g1_position(self, s, phi):
        """The G₁ texture's coordinates ``(φ, s)`` of ``s = √cosθ`` and the azimuth (node-centred, φ's end node
        repeating its first)."""
        assert self.host.g1 is not None
        ns, nphi = self.host.g1.shape[1:]
        return (phi / (2 * math.pi) * (nphi - 1) + 0.5) / nphi, (s * (ns - 1) + 0.5) / ns

    def density(self, m, level, active):
        import drjit as dr

        half = self.host.half
        pos = self.mi.Point2f((m.x + half) / (2 * half), (m.y + half) / (2 * half))
        inside = (dr.abs(m.x) < half) & (dr.abs(m.y) < half)
        return dr.select(inside, self.sampler.eval(pos, [level[1]], active & inside) / (4 * half * half), 0.0)

    def sample(self, sample2, level, active):
        half = self.host.half
        pos, _ = self.sampler.sample(sample2, [level[1]], active)
        return pos * (2 * half) - half

    def _g1_at(self, w, z):
        import drjit as dr

        mi = self.mi
        s = dr.sqrt(dr.clip(mi.Frame3f.cos_theta(w), 0.0, 1.0))
        phi = dr.atan2(w.y, w.x)
        phi = dr.select(phi < 0, phi + 2 * math.pi, phi)
        assert self.host.g1 is not None and self.g1 is not None  # masking asks only when there are tables
        pphi, ps = self._g1_position(s, phi)
        return dr.clip(self._fetch(self.g1, mi.Point3f(pphi, ps, z)), 0.0, 1.0)

    def masking(self, wi, wo, level):
        import drjit as dr

        if self.g1 is None:
            return self.mi.Float(1.0)
        a, b = self._g1_at(wi, level[0]), self._g1_at(wo, level[0])
        if not getattr(self.host.masking, "correlated", True):
            return a * b
        den = a + b - a * b  # G₂ = 1/(1 + Λ_i + Λ_o) with Λ = 1/G₁ − 1
        return dr.select(den > 0, a * b / den, 0.0)

    def tensor(self):
        return self.table

    def changed(self):
        self.tex.set_tensor(self.table)


class _SplineLobe(_TableLobe):
    """The spline form in Dr.Jit (:class:`Splines`): Dr.Jit's ``eval_cubic`` of the coefficient textures (lobe and
    G₁) at the run of the ladder that holds ln μ; sampling and its density are the table form's, from the values at
    the nodes."""

    key = "coefficients"
    host: Splines

    def __init__(self, mi, host: Splines):
        super().__init__(mi, host, host.coefficients)
        self.depth = host.coefficients.shape[0]

    def at(self, log_mu):
        """The level: the texture coordinate of ln μ in its run's block (:func:`._spline.runs_coefficients`) and
        ln μ (for the sampler)."""
        import drjit as dr

        start, step, count, offset = (self.mi.Float(v) for v in self.host.runs[0])
        for run in self.host.runs[1:]:
            later = log_mu >= run[0]
            start, step, count, offset = (dr.select(later, v, old) for v, old in zip(run, (start, step, count, offset)))
        j = dr.clip((log_mu - start) / step, 0.0, count - 1.0)
        return (offset + GHOSTS + j + 0.5) / self.depth, log_mu

    @staticmethod
    def _fetch(texture, point):
        """The cubic B-spline of the texture's coefficients at ``point`` (:mod:`._spline`)."""
        return texture.eval_cubic(point)[0]

    def _g1_position(self, s, phi):
        """The coordinates ``(φ, s)`` in the G₁ coefficients: ghost nodes beyond the ends of s, φ periodic with
        wrapped padding."""
        assert self.host.g1 is not None
        height, width = self.host.g1.shape[1:]  # n_s + 2·GHOSTS, n_φ − 1 + 2·PERIODIC_PAD
        ps = (s * (height - 2 * GHOSTS - 1) + GHOSTS + 0.5) / height
        pphi = (phi / (2 * math.pi) * (width - 2 * PERIODIC_PAD) + PERIODIC_PAD + 0.5) / width
        return pphi, ps


class _GaussianLobe:
    """Gaussian lobes in closed form in Dr.Jit (module docstring): the parameters of the two neighbouring scales
    gathered and mixed linearly in ln μ; ``A·N(m; c, Σ)``, its exact sampling ``m = c + L z`` (Box–Muller z,
    ``Σ = L Lᵀ``) and Smith's ``Λ(w) = s φ(1/s) − Φ(−1/s)``, ``s² = vᵀΣv``, ``v = w_xy/w_z``
    (:mod:`brdfscale.stats._masking`'s closed form)."""

    key = "parameters"

    def __init__(self, mi, host: Gaussians):
        self.mi, self.host = mi, host
        self.levels = len(host.parameters)
        flat = np.ascontiguousarray(host.parameters.ravel(), dtype=np.float32)
        self.params = mi.Float(flat) if dr_jit(mi) else mi.TensorXf(flat)  # scalar variants: not differentiable
        self.logs = mi.Float(np.asarray(host.log_mu, np.float32)) if dr_jit(mi) else None

    def at(self, log_mu):
        """The level: ``(A, c_x, c_y, Σ_xx, Σ_xy, Σ_yy)`` at ln μ, linear in ln μ between the two neighbouring scales
        (found by binary search: a refined ladder may hold thousands)."""
        import drjit as dr

        mi, x, L = self.mi, self.host.log_mu, self.levels
        if not dr_jit(mi):  # scalar variants: one interaction, the host's parameters
            k = int(min(max(np.searchsorted(x, float(log_mu)) - 1, 0), L - 2))
            f = min(max((float(log_mu) - x[k]) / (x[k + 1] - x[k]), 0.0), 1.0)
            return tuple(float(v) for v in (1 - f) * self.host.parameters[k] + f * self.host.parameters[k + 1])
        k = dr.binary_search(0, L - 2, lambda idx: dr.gather(mi.Float, self.logs, idx + 1) < log_mu)
        a, b = dr.gather(mi.Float, self.logs, k), dr.gather(mi.Float, self.logs, k + 1)
        f = dr.clip((log_mu - a) / (b - a), 0.0, 1.0)
        return tuple(
            (1 - f) * dr.gather(mi.Float, self.params, 6 * k + c) + f * dr.gather(mi.Float, self.params, 6 * k + 6 + c)
            for c in range(6)
        )

    @staticmethod
    def _normal(dr, m, level):
        """``N(m; c, Σ)`` per unit slope area."""
        _, cx, cy, sxx, sxy, syy = level
        det = sxx * syy - sxy * sxy
        dx, dy = m.x - cx, m.y - cy
        q = (syy * dx * dx - 2 * sxy * dx * dy + sxx * dy * dy) / det
        return dr.exp(-0.5 * q) / (2 * math.pi * dr.sqrt(det))

    def value(self, m, level):
        import drjit as dr

        return level[0] * self._normal(dr, m, level)

    def density(self, m, level, active):
        import drjit as dr

        return dr.select(active, self._normal(dr, m, level), 0.0)

    def sample(self, sample2, level, active):
        import drjit as dr

        _, cx, cy, sxx, sxy, syy = level
        r = dr.sqrt(-2 * dr.log(dr.maximum(1 - sample2.x, 1e-30)))
        s, c = dr.sincos(2 * math.pi * sample2.y)
        zx, zy = r * c, r * s
        l00 = dr.sqrt(sxx)
        l10 = sxy / l00
        l11 = dr.sqrt(dr.maximum(syy - l10 * l10, 0.0))
        return self.mi.Point2f(cx + l00 * zx, cy + l10 * zx + l11 * zy)

    def _lambda(self, w, level):
        import drjit as dr

        _, _, _, sxx, sxy, syy = level
        wz = dr.maximum(w.z, 1e-30)
        vx, vy = w.x / wz, w.y / wz
        s2 = vx * vx * sxx + 2 * vx * vy * sxy + vy * vy * syy
        a = 1 / dr.sqrt(2 * dr.maximum(s2, 1e-30))  # a = μ/α along w's azimuth
        lam = dr.exp(-a * a) / (2 * a * math.sqrt(math.pi)) - 0.5 * (1 - dr.erf(a))
        return dr.select(s2 > 0, dr.maximum(lam, 0.0), 0.0)

    def masking(self, wi, wo, level):
        if self.host.masking is None:
            return self.mi.Float(1.0)
        li, lo = self._lambda(wi, level), self._lambda(wo, level)
        if getattr(self.host.masking, "correlated", True):
            return 1 / (1 + li + lo)
        return 1 / ((1 + li) * (1 + lo))

    def tensor(self):
        return self.params

    def changed(self):
        pass


def footprint(si):
    """The footprint length ``√|dp/dx × dp/dy|`` of an interaction (scene length units), from its uv partials:
    ``dp/dx = ∂p/∂u · du/dx + ∂p/∂v · dv/dx`` (and y), as ``si.compute_uv_partials(ray)`` fills them from the ray
    differentials (one pixel's step); 0 where they are not filled."""
    import drjit as dr

    dp_dx = si.dp_du * si.duv_dx.x + si.dp_dv * si.duv_dx.y
    dp_dy = si.dp_du * si.duv_dy.x + si.dp_dv * si.duv_dy.y
    return dr.sqrt(dr.norm(dr.cross(dp_dx, dp_dy)))


@per_variant
def bsdf_class(mi) -> type:
    """The BSDF class for the current variant of ``mi`` (built once per variant: Mitsuba's types depend on it)."""
    import drjit as dr

    class BrdfscaleBSDF(mi.BSDF):
        """brdfscale's evolved lobe as a Mitsuba BSDF (module docstring of brdfscale/render/_plugin.py)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags
            self._ready = False
            if "filename" in props:
                self.load(scene_tables(props))

        def load(self, host: Host):
            self._host = host
            self._lobe = host.renderer(mi)
            self._ready = True

        @property
        def host(self) -> Host:
            """What this BSDF renders, host-side (:class:`Tables` or :class:`Gaussians`): its ladder ``log_mu``,
            fixed ``mu``, ``texel``, ``masking`` and its lobe's values (``values``) or parameters
            (``parameters``)."""
            return self._host

        # -- the scale μ ----------------------------------------------------------------------------------------
        def _log_mu(self, si):
            lo, hi = self._host.log_mu[0], self._host.log_mu[-1]
            if self._host.mu is not None:
                return mi.Float(min(max(math.log(self._host.mu), lo), hi))
            mu = footprint(si) / self._host.texel
            return dr.clip(dr.log(dr.maximum(mu, 1e-30)), lo, hi)

        def _half(self, wi, wo):
            h = dr.normalize(wi + wo)
            return h, mi.Point2f(h.x / h.z, h.y / h.z)

        # -- Mitsuba's interface --------------------------------------------------------------------------------
        def _value(self, si, wo, active):
            wi = si.wi
            ci, co = mi.Frame3f.cos_theta(wi), mi.Frame3f.cos_theta(wo)
            active = active & (ci > 0) & (co > 0)
            h, m = self._half(wi, wo)
            level = self._lobe.at(self._log_mu(si))
            value = (
                self._lobe.value(m, level) / (4 * ci * dr.square(dr.square(h.z))) * self._lobe.masking(wi, wo, level)
            )
            return dr.select(active, value, 0.0), active

        def _density(self, si, wo, active):
            wi = si.wi
            ci, co = mi.Frame3f.cos_theta(wi), mi.Frame3f.cos_theta(wo)
            h, m = self._half(wi, wo)
            active = active & (ci > 0) & (co > 0)
            p_m = self._lobe.density(m, self._lobe.at(self._log_mu(si)), active)
            cos_ih = dr.dot(wi, h)
            pdf = p_m / (h.z * h.z * h.z * 4 * cos_ih)
            return dr.select(active & (cos_ih > 0) & (p_m > 0), pdf, 0.0)

        def eval(self, ctx, si, wo, active=True):
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
                return mi.Spectrum(0.0)
            value, _ = self._value(si, wo, active)
            return mi.Spectrum(value)

        def pdf(self, ctx, si, wo, active=True):
            if not ctx.is_enabled(mi.BSDFFlags.GlossyReflection):
                return mi.Float(0.0)
            return self._density(si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            wi = si.wi
            m = self._lobe.sample(sample2, self._lobe.at(self._log_mu(si)), active)
            h = dr.normalize(mi.Vector3f(m.x, m.y, 1.0))
            wo = 2 * dr.dot(wi, h) * h - wi
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = self._density(si, wo, active)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            value, ok = self._value(si, wo, active)
            ok = ok & (bs.pdf > 0) & ctx.is_enabled(mi.BSDFFlags.GlossyReflection)
            return bs, mi.Spectrum(dr.select(ok, value / dr.maximum(bs.pdf, 1e-30), 0.0))

        def traverse(self, callback):
            callback.put(self._lobe.key, self._lobe.tensor(), mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            self._lobe.changed()

        def to_string(self):
            host = self._host
            mu = "from the footprint" if host.mu is None else f"{host.mu:g}"
            return (
                f"BrdfscaleBSDF[form={host.form}, levels={self._lobe.levels}, mu={mu}, texel={host.texel:g}, "
                f"masking={type(host.masking).__name__ if host.masking is not None else 'none'}]"
            )

    return BrdfscaleBSDF


def scene_tables(props) -> "Tables":
    """The :class:`Tables` a scene's ``{"type": "brdfscale", "filename": …, "mu": …, "masking": …, "texel": …}``
    asks for, each value checked as :func:`brdfscale.render.bsdf` checks it: ``mu`` positive (absent: the footprint),
    ``texel`` positive, ``masking`` what ``bsdf`` accepts."""
    from ._masking import masking_choice

    mu = props.get("mu") if "mu" in props else None
    if mu is not None:
        mu = check_positive(mu, "mu", "a fixed scale; omit it to take the scale from the ray footprint")
    texel = check_positive(props.get("texel", 1.0), "texel", "the scene length of one unit of μ")
    masking = masking_choice(props.get("masking", True))
    return Tables(read_lobe_table(str(props.get("filename"))), masking, mu=mu, texel=texel)


def check_filename(props) -> None:
    """A scene's ``"brdfscale"`` BSDF needs ``filename`` (the Python-built one, :func:`brdfscale.render.bsdf`, is
    loaded by its builder instead)."""
    if "filename" not in props:
        raise InvalidInputError(
            "the 'brdfscale' BSDF of a scene needs filename= (an evolved lobe table: brdfscale.exr.write_lobe_table "
            "of brdfscale.render.lobe_table(...)); or build the BSDF in Python with brdfscale.render.bsdf(...) and "
            "put that object in the scene dictionary."
        )


def check_positive(value, name: str, what: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = float("nan")
    if isinstance(value, bool) or not math.isfinite(x) or x <= 0:
        raise InvalidInputError(f"{name} must be a positive number ({what}); got {value!r}.")
    return x
