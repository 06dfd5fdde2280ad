"""A scale-aware BSDF for Mitsuba 3 and engine roughness export (issue 33; extra ``brdfscale[render]``).

* :func:`bsdf` — a Mitsuba BSDF object: a base lobe at μ0 evolved with its statistics to each interaction's scale
  μ (tables precomputed in JAX on a log-μ ladder, interpolated in Mitsuba); :func:`lobe_table` — those tables;
* :func:`register` — the plugins ``"brdfscale"`` (BSDF, from an EXR lobe table) and ``"brdfscale_footprint"``
  (integrator) for ``mi.load_dict``; :func:`FootprintIntegrator` — the integrator that gives each pixel's first hit
  its footprint as the observation scale;
* :func:`export_roughness` — per-texel, per-mip anisotropic roughness for engines, as EXR.

Nothing here imports Mitsuba until called (brdfscale._mitsuba picks the variant). Guide: docs/render.md.
"""

from ._api import bsdf, FootprintIntegrator, register
from ._export import CONVENTIONS, export_roughness
from ._material import lobe_table


__all__ = ["bsdf", "register", "lobe_table", "FootprintIntegrator", "export_roughness", "CONVENTIONS"]
