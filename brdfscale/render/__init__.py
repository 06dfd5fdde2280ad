"""A scale-aware BSDF for Mitsuba 3 and engine roughness export (issue 33; extra ``brdfscale[render]``)."""
