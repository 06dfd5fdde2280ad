"""The integrator ``"brdfscale_footprint"``: a path tracer that gives each primary hit its pixel footprint.

Mitsuba's stock integrators never fill the uv partials a BSDF would need for a footprint (``si.duv_dx`` stays 0 for
a Python BSDF; Mitsuba issue 788): this one calls ``si.compute_uv_partials(ray)`` with the camera ray's
differentials at the first hit, so the ``"brdfscale"`` BSDF (:mod:`._plugin`) reads the footprint length
``√|dp/dx × dp/dy|`` — the square root of the area one pixel covers on the surface, in the scene's length units —
and divides it by its ``texel`` to get μ. The render loop scales camera differentials by ``1/√spp`` (each sample's
share of the pixel); ``footprint="pixel"`` (default) undoes that, so μ is the pixel's footprint whatever the sample
count, ``footprint="sample"`` keeps Mitsuba's scaling.

Light transport: unidirectional path tracing with emitter sampling and BSDF sampling combined by the power
heuristic, ``max_depth`` path segments (2: direct lighting only). Only the first hit has a footprint: later
interactions have none and the BSDF uses its ladder's finest scale there (or its fixed μ). ``output="footprint"``
renders the first hit's footprint length instead of radiance (0 where nothing is hit): the quantity the BSDF sees.
"""

from .._choices import FOOTPRINTS, OUTPUTS
from .._validation import integer
from ._plugin import footprint
from ._variants import per_variant


INTEGRATOR = "brdfscale_footprint"
"""The name the integrator is registered under (:func:`brdfscale.render.register`)."""


def check_options(max_depth, output, footprint) -> tuple[int, str, str]:
    """The integrator's options, or InvalidInputError naming what is accepted."""
    max_depth = integer(max_depth, "max_depth", 1)  # path segments; Python or NumPy integers
    OUTPUTS.check(output)
    FOOTPRINTS.check(footprint)
    return max_depth, output, footprint


def _mis(a, b):
    """The power heuristic ``a²/(a² + b²)`` (0 where both vanish)."""
    import drjit as dr

    a2, b2 = dr.square(a), dr.square(b)
    return dr.select(a2 + b2 > 0, a2 / (a2 + b2), 0.0)


@per_variant
def integrator_class(mi) -> type:
    """The integrator class for the current variant of ``mi`` (built once per variant)."""
    import drjit as dr

    class FootprintIntegrator(mi.SamplingIntegrator):
        """Path tracing with ray-differential footprints at the first hit (module docstring)."""

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.max_depth, self.output, self.footprint = check_options(
                props.get("max_depth", 3),
                props.get("output", OUTPUTS.default),
                props.get("footprint", FOOTPRINTS.default),
            )

        def sample(self, scene, sampler, ray, medium=None, active=True):
            ray = mi.RayDifferential3f(ray) if not isinstance(ray, mi.RayDifferential3f) else ray
            if self.footprint == "pixel":
                ray.scale_differential(dr.sqrt(mi.Float(sampler.sample_count())))
            ctx = mi.BSDFContext()
            result = mi.Spectrum(0.0)
            throughput = mi.Spectrum(1.0)
            active = mi.Bool(active)
            prev_si = dr.zeros(mi.SurfaceInteraction3f)
            prev_pdf = mi.Float(1.0)
            prev_delta = mi.Bool(True)
            si = scene.ray_intersect(ray, active)
            si.compute_uv_partials(ray)
            if self.output == "footprint":
                value = dr.select(si.is_valid(), footprint(si), 0.0)
                return mi.Spectrum(value), si.is_valid(), []
            jit = dr.is_jit_v(mi.Float)
            for depth in range(self.max_depth):
                if depth > 0:
                    si = scene.ray_intersect(ray, active)
                # emitters hit by the previous BSDF sample (or by the camera ray)
                emitter = si.emitter(scene, active)
                hit_emitter = active & (emitter != None)  # noqa: E711 (a Dr.Jit pointer array)
                mis_needed = hit_emitter & dr.select(prev_delta, False, True)
                if jit or mis_needed:  # scalar variants would dereference a missing emitter
                    ds = mi.DirectionSample3f(scene, si, prev_si)
                    em_pdf = scene.pdf_emitter_direction(prev_si, ds, mis_needed)
                    weight = dr.select(mis_needed, _mis(prev_pdf, em_pdf), 1.0)
                else:
                    weight = mi.Float(1.0)
                if jit or hit_emitter:
                    result += dr.select(hit_emitter, throughput * weight * emitter.eval(si, hit_emitter), 0.0)
                active &= si.is_valid()
                if depth + 1 == self.max_depth or not (jit or active):  # scalar: nothing hit, nothing to shade
                    break
                bsdf = si.bsdf(ray)
                # emitter sampling
                smooth = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(smooth), True, smooth)
                smooth &= ds.pdf != 0
                wo = si.to_local(ds.d)
                value, pdf = bsdf.eval_pdf(ctx, si, wo, smooth)
                weight = dr.select(ds.delta, 1.0, _mis(ds.pdf, pdf))
                result += dr.select(smooth, throughput * value * em_weight * weight, 0.0)
                # BSDF sampling
                bs, bsdf_weight = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
                throughput *= bsdf_weight
                active &= (bs.pdf > 0) & dr.any(throughput != 0)
                prev_si = mi.SurfaceInteraction3f(si)
                prev_pdf = bs.pdf
                prev_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                ray = mi.RayDifferential3f(si.spawn_ray(si.to_world(bs.wo)))
            return result, mi.Bool(True), []

        def aov_names(self):
            return []

        def to_string(self):
            return f"FootprintIntegrator[max_depth={self.max_depth}, output={self.output}, footprint={self.footprint}]"

    return FootprintIntegrator
