"""The facets' own reflection (micro-BRDF) as a Mitsuba BSDF: mirror, Beckmann or GGX, with an optional Fresnel term.

Accepted ``micro`` objects (the choice carries its behaviour: :func:`micro_bsdf` turns it into Mitsuba's plugin):

* :class:`brdfscale.lobes.Mirror`, :class:`~brdfscale.lobes.Beckmann`, :class:`~brdfscale.lobes.GGX` — the lobe's
  shape is the facets' micro-normal slope density and its amplitude A their reflectance (A ≤ 1);
* the :mod:`brdfscale.stats` densities a :class:`brdfscale.synth.HeightField` carries as ``micro``:
  ``stats.Delta()`` (mirror), a centred ``stats.Gaussian``/``stats.Beckmann`` and a centred ``stats.GGX``
  (reflectance 1).

Rough micro-facets must be isotropic: the mesh's triangles have no tangent frame aligned with the field's axes.

Mitsuba's microfacet distributions use the same slope densities as the library (Beckmann: per-axis slope variance
α²/2; GGX: bivariate Student-t with ν = 2; checked in
tests/test_stats.py::test_against_mitsuba_microfacet_distribution).
Mirror facets are Mitsuba's ``conductor``, rough ones ``roughconductor`` (visible-normal sampling; Smith masking
G₁·G₁ of the micro-surface inside each facet, Mitsuba's rational approximation for Beckmann, < 0.35 %).

``fresnel``: None (F = 1: a lossless facet, reflectance A) or the facets' complex refractive index ``n + i k``
(a conductor; a real ``n`` gives a dielectric's reflectance, the transmitted light is lost).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .. import lobes, stats
from .._errors import InvalidInputError


ACCEPTED = (
    "lobes.Mirror(), lobes.Beckmann(alpha) or lobes.GGX(alpha) (isotropic; amplitude ≤ 1: the facets' reflectance), "
    "stats.Delta(), a centred isotropic stats.Beckmann/Gaussian or stats.GGX, or None (the field's micro)"
)


@dataclasses.dataclass(frozen=True)
class Micro:
    """The resolved micro-BRDF: ``kind`` ``"mirror"``, ``"beckmann"`` or ``"ggx"``, roughness ``(α_x, α_y)``,
    reflectance ``amplitude`` and ``fresnel`` (None or a complex index)."""

    kind: str
    alpha: tuple[float, float]
    amplitude: float
    fresnel: complex | None

    def record(self) -> dict:
        return {
            "type": self.kind,
            "alpha": list(self.alpha),
            "amplitude": self.amplitude,
            "fresnel": None if self.fresnel is None else [self.fresnel.real, self.fresnel.imag],
        }

    def bsdf(self) -> dict:
        """Mitsuba's plugin dictionary for this micro-BRDF."""
        if self.fresnel is None:
            material = {"material": "none"}
        else:
            material = {"eta": float(self.fresnel.real), "k": float(self.fresnel.imag)}
        scale = {"specular_reflectance": {"type": "rgb", "value": [self.amplitude] * 3}}
        if self.kind == "mirror":
            return {"type": "conductor", **material, **scale}
        return {
            "type": "roughconductor",
            "distribution": self.kind,
            "alpha_u": self.alpha[0],
            "alpha_v": self.alpha[1],
            "sample_visible": True,
            **material,
            **scale,
        }


def _centred(density) -> bool:
    return getattr(density, "mean", None) is None


def resolve(micro, fresnel) -> Micro:
    """``micro`` and ``fresnel`` checked and resolved (:data:`ACCEPTED`); InvalidInputError naming what is accepted."""
    amplitude = 1.0
    shape = micro
    if isinstance(micro, (lobes.Mirror, lobes.Beckmann, lobes.GGX)):
        amplitude = float(np.asarray(micro.amplitude))
        shape = micro.shape
        if not 0 < amplitude <= 1:
            raise InvalidInputError(
                f"micro's amplitude is the facets' reflectance, in (0, 1]; got {amplitude!r} (accepted: {ACCEPTED})."
            )
    kind, alpha = None, (0.0, 0.0)
    if isinstance(shape, stats.Delta) and _centred(shape):
        kind = "mirror"
    elif isinstance(shape, stats.Gaussian) and _centred(shape):
        cov = np.asarray(shape.cov, dtype=float)
        if cov.shape == (2, 2) and cov[0, 1] == 0 and cov[1, 0] == 0:
            kind, alpha = "beckmann", (float(np.sqrt(2 * cov[0, 0])), float(np.sqrt(2 * cov[1, 1])))
    elif isinstance(shape, stats.GGX) and _centred(shape):
        a = np.broadcast_to(np.asarray(shape.alpha, dtype=float), (2,))
        kind, alpha = "ggx", (float(a[0]), float(a[1]))
    if kind is None:
        raise InvalidInputError(f"micro must be {ACCEPTED}; got {type(micro).__name__} {micro!r:.200}.")
    if kind != "mirror" and not all(0 < a < np.inf for a in alpha):
        raise InvalidInputError(f"micro's roughness must be positive and finite; got alpha={alpha} ({ACCEPTED}).")
    if alpha[0] != alpha[1]:
        raise InvalidInputError(
            f"micro must be isotropic (alpha_x = alpha_y); got alpha={alpha}: the mesh's triangles carry no tangent "
            "frame aligned with the field's x axis, so an anisotropic micro-BRDF would be oriented at random. "
            f"Accepted: {ACCEPTED}."
        )
    if fresnel is not None:
        if isinstance(fresnel, (bool, np.bool_)) or not isinstance(
            fresnel, (int, float, complex, np.integer, np.floating, np.complexfloating)
        ):
            raise InvalidInputError(
                "fresnel must be None (no Fresnel factor) or the facets' refractive index, a real n or complex "
                f"n + ik with n > 0, k ≥ 0; got {type(fresnel).__name__}."
            )
        fresnel = complex(fresnel)
        if not (np.isfinite(fresnel.real) and np.isfinite(fresnel.imag) and fresnel.real > 0 and fresnel.imag >= 0):
            raise InvalidInputError(
                f"fresnel must be a refractive index n + ik with finite n > 0 and k ≥ 0; got {fresnel!r}."
            )
    return Micro(kind, alpha, amplitude, fresnel)
