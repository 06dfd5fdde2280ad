"""Reference implementations written independently of brdfscale (mpmath, SciPy quadrature,
NumPy), against which the tests — and the experiments that measure accuracy — check the
library: ``planner`` (the evolution paths' reference problems), ``plus_transform`` (the
plus-distribution transforms H_n), ``topography_mutation`` (damaged instrument files and what
SurfaceTopography decodes from them), ``damage`` (damaged checkpoints and full disks, made
without brdfscale's writers)."""
