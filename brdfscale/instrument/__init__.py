"""A ray-traced multi-scale gonioreflectometer on Mitsuba 3 (issue 32; extra ``brdfscale[render]``)."""
