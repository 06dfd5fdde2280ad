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
import threading

import numpy as np

from .._errors import InvalidInputError
from ..exr import read_lobe_table
from ._masking import g1_table, table_shapes
from ._material import scalar_table


PLUGIN = "brdfscale"
"""The name the BSDF is registered under (:func:`brdfscale.render.register`)."""

_CLASSES: dict[str, type] = {}
_LOCK = threading.Lock()


class Tables:
    """What the plugin renders, host-side: the padded lobe values, the ladder and the masking tables.

    ``shapes``: the lobe shapes whose Smith Λ makes the masking tables (default the table's own, tabulated).
    """

    def __init__(self, table, masking, *, mu=None, texel=1.0, shapes=None):
        values = scalar_table(table)
        k, n, _ = values.shape
        h = 2 * table.extent / (n - 1)
        padded = np.pad(values, ((0, 0), (1, 1), (1, 1)))  # the zero ring of the tent sum
        scales = np.asarray(table.scales, float)
        if k == 1:  # one scale: a constant ladder of two equal planes keeps one code path
            padded = np.concatenate([padded, padded])
            scales = np.array([scales[0], scales[0] * math.e])
        self.values = padded  # (L, N, N), rows u_y, columns u_x
        self.log_mu = [float(x) for x in np.log(scales)]
        self.half = float(table.extent + h)  # the padded grid spans [−half, half]²
        self.masking = masking
        self.g1 = None
        if masking is not None:
            g1 = g1_table(table_shapes(table) if shapes is None else shapes)
            self.g1 = np.concatenate([g1, g1]) if k == 1 else g1  # (L, n_s, n_phi)
        self.mu = None if mu is None else float(mu)
        self.texel = float(texel)


def footprint(si):
    """The footprint length ``√|dp/dx × dp/dy|`` of an interaction (scene length units), from its uv partials:
    ``dp/dx = ∂p/∂u · du/dx + ∂p/∂v · dv/dx`` (and y), as ``si.compute_uv_partials(ray)`` fills them from the ray
    differentials (one pixel's step); 0 where they are not filled."""
    import drjit as dr

    dp_dx = si.dp_du * si.duv_dx.x + si.dp_dv * si.duv_dx.y
    dp_dy = si.dp_du * si.duv_dy.x + si.dp_dv * si.duv_dy.y
    return dr.sqrt(dr.norm(dr.cross(dp_dx, dp_dy)))


def _build(mi):
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
                mu = props.get("mu", 0.0)
                masking = props.get("masking", True)
                from ._masking import masking_choice

                tables = Tables(
                    read_lobe_table(str(props.get("filename"))),
                    masking_choice(bool(masking)),
                    mu=None if mu <= 0 else mu,
                    texel=props.get("texel", 1.0),
                )
                self.load(tables)

        def load(self, tables: Tables):
            self._host = tables
            L, N, _ = tables.values.shape
            self._levels, self._nodes = L, N
            self._table = mi.TensorXf(np.ascontiguousarray(tables.values[..., None], dtype=np.float32))
            self._tex = mi.Texture3f(self._table)
            self._sampler = mi.MarginalContinuous2D1(
                np.ascontiguousarray(np.maximum(tables.values, 0.0), dtype=np.float32), [tables.log_mu]
            )
            self._g1 = None
            if tables.g1 is not None:
                self._g1 = mi.Texture3f(mi.TensorXf(np.ascontiguousarray(tables.g1[..., None], dtype=np.float32)))
                self._correlated = bool(getattr(tables.masking, "correlated", True))
            self._ready = True

        # -- the scale μ ----------------------------------------------------------------------------------------
        def _log_mu(self, si):
            lo, hi = self._host.log_mu[0], self._host.log_mu[-1]
            if self._host.mu is not None:
                return mi.Float(min(max(math.log(self._host.mu), lo), hi))
            mu = footprint(si) / self._host.texel
            return dr.clip(dr.log(dr.maximum(mu, 1e-30)), lo, hi)

        def _level(self, log_mu):
            """Texture coordinate along the ladder: the piecewise-linear index j(ln μ), texel-centred."""
            x = self._host.log_mu
            j = mi.Float(0.0)
            for a, b in zip(x[:-1], x[1:]):
                j += dr.clip((log_mu - a) / (b - a), 0.0, 1.0)
            return (j + 0.5) / self._levels

        def _lobe(self, m, z):
            n, half = self._nodes, self._host.half
            px = ((m.x + half) / (2 * half) * (n - 1) + 0.5) / n
            py = ((m.y + half) / (2 * half) * (n - 1) + 0.5) / n
            inside = (dr.abs(m.x) < half) & (dr.abs(m.y) < half)
            # an evolved lobe may dip below 0 (regularisation ringing): shaded as 0, as it is sampled
            return dr.select(inside, dr.maximum(self._tex.eval(mi.Point3f(px, py, z))[0], 0.0), 0.0)

        def _g1_at(self, w, z):
            s = dr.sqrt(dr.clip(mi.Frame3f.cos_theta(w), 0.0, 1.0))
            phi = dr.atan2(w.y, w.x)
            phi = dr.select(phi < 0, phi + 2 * math.pi, phi)
            assert self._host.g1 is not None and self._g1 is not None  # _masking asks only when there are tables
            ns, nphi = self._host.g1.shape[1:]
            ps = (s * (ns - 1) + 0.5) / ns
            pphi = (phi / (2 * math.pi) * (nphi - 1) + 0.5) / nphi
            return dr.clip(self._g1.eval(mi.Point3f(pphi, ps, z))[0], 0.0, 1.0)

        def _masking(self, wi, wo, z):
            if self._g1 is None:
                return mi.Float(1.0)
            a, b = self._g1_at(wi, z), self._g1_at(wo, z)
            if not self._correlated:
                return a * b
            den = a + b - a * b  # G₂ = 1/(1 + Λ_i + Λ_o) with Λ = 1/G₁ − 1
            return dr.select(den > 0, a * b / den, 0.0)

        def _half(self, wi, wo):
            h = dr.normalize(wi + wo)
            return h, mi.Point2f(h.x / h.z, h.y / h.z)

        # -- Mitsuba's interface --------------------------------------------------------------------------------
        def _value(self, si, wo, active):
            wi = si.wi
            ci, co = mi.Frame3f.cos_theta(wi), mi.Frame3f.cos_theta(wo)
            active = active & (ci > 0) & (co > 0)
            h, m = self._half(wi, wo)
            z = self._level(self._log_mu(si))
            value = self._lobe(m, z) / (4 * ci * dr.square(dr.square(h.z))) * self._masking(wi, wo, z)
            return dr.select(active, value, 0.0), active

        def _density(self, si, wo, active):
            wi = si.wi
            ci, co = mi.Frame3f.cos_theta(wi), mi.Frame3f.cos_theta(wo)
            h, m = self._half(wi, wo)
            active = active & (ci > 0) & (co > 0)
            half = self._host.half
            pos = mi.Point2f((m.x + half) / (2 * half), (m.y + half) / (2 * half))
            inside = (dr.abs(m.x) < half) & (dr.abs(m.y) < half)
            p_unit = self._sampler.eval(pos, [self._log_mu(si)], active & inside)
            p_m = p_unit / (4 * half * half)
            cos_ih = dr.dot(wi, h)
            pdf = p_m / (h.z * h.z * h.z * 4 * cos_ih)
            return dr.select(active & inside & (cos_ih > 0), pdf, 0.0)

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
            half = self._host.half
            pos, _ = self._sampler.sample(sample2, [self._log_mu(si)], active)
            m = pos * (2 * half) - half
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
            callback.put("table", self._table, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            self._tex.set_tensor(self._table)

        def to_string(self):
            host = self._host
            mu = "from the footprint" if host.mu is None else f"{host.mu:g}"
            return (
                f"BrdfscaleBSDF[levels={self._levels}, mu={mu}, texel={host.texel:g}, "
                f"masking={type(host.masking).__name__ if host.masking is not None else 'none'}]"
            )

    return BrdfscaleBSDF


def bsdf_class(mi) -> type:
    """The BSDF class for the current variant of ``mi`` (one per variant: Mitsuba's types depend on it)."""
    variant = mi.variant()
    with _LOCK:
        if variant not in _CLASSES:
            _CLASSES[variant] = _build(mi)
        return _CLASSES[variant]


def check_positive(value, name: str, what: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = float("nan")
    if isinstance(value, bool) or not math.isfinite(x) or x <= 0:
        raise InvalidInputError(f"{name} must be a positive number ({what}); got {value!r}.")
    return x
