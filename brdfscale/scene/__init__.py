"""Scene planning: compute only what a scene needs, as cheaply as its error target allows.

* :class:`Material` — a lobe at scale μ0 and the scale law of its facet statistics;
* :class:`AnisotropicMaterial` — a BRDF of the facet's orientation on SO(3) (tilt and twist)
  at μ0 and its rotational-diffusion scale law (planned on the SO(3) path);
* :class:`Queries` — the (i, o, m∞, twist, μ, material) tuples present;
* :class:`Scene` — materials, queries and an error target; :class:`Camera` and
  :func:`camera_scene` make one from a camera looking at a textured plane;
* :func:`plan` — the planner (path per material, sizes or band limits from a-priori bounds,
  scale binning);
* :class:`Plan` — ``evaluate()`` (jit-compiled, differentiable), ``image()``, ``explain()``.
"""

from ._description import AnisotropicMaterial, Camera, camera_scene, Material, Queries, Scene
from ._plan import Plan
from ._planner import plan


__all__ = ["Material", "AnisotropicMaterial", "Queries", "Scene", "Camera", "camera_scene", "plan", "Plan"]
