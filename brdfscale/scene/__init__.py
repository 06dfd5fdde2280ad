"""Scene planning: compute only what a scene needs, as cheaply as its error target allows.

* :class:`Material` — a lobe at scale μ0 and the scale law of its facet statistics;
* :class:`Queries` — the (i, o, m∞, μ, material) tuples present;
* :class:`Scene` — materials, queries and an error target; :class:`Camera` and
  :func:`camera_scene` make one from a camera looking at a textured plane;
* :func:`plan` — the planner (path per material, sizes from a-priori bounds, scale binning);
* :class:`Plan` — ``evaluate()`` (jit-compiled, differentiable), ``image()``, ``explain()``.
"""

from ._description import Camera, Material, Queries, Scene, camera_scene
from ._plan import Plan
from ._planner import plan

__all__ = ["Material", "Queries", "Scene", "Camera", "camera_scene", "plan", "Plan"]
