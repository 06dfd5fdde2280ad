"""The evaluation plan: frozen discretisation choices, a jit-compiled differentiable evaluation."""

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import InvalidInputError
from .._show import Shown, Table
from . import _cost
from ._description import AnisotropicMaterial, Material
from ._steps import MaterialPlan


class _plain_method:
    """A method that equinox does not wrap into a pytree ``BoundMethod`` on every attribute
    access: that wrapping costs about 0.1 ms per access, more than evaluating a small plan."""

    def __init__(self, fn):
        self.fn = fn
        # typeshed types the wrapper as a callable; update_wrapper copies the metadata onto any object
        functools.update_wrapper(self, fn)  # pyright: ignore[reportArgumentType]

    def __get__(self, obj, owner=None):
        return self.fn if obj is None else functools.partial(self.fn, obj)


class Plan(Shown, eqx.Module):
    """What to compute for a scene, and how (built by :func:`brdfscale.scene.plan`).

    ``evaluate()`` returns ``ρ(i, o, m∞, μ)`` (1/sr, seed §2: ρ = β cos θ_i) for every query of
    the scene, in the scene's order. It is jit-compiled and differentiable in the materials'
    parameters: pass ``materials=`` of the same structure (e.g. from a fit) to evaluate the
    same plan with other values, or differentiate through ``plan.evaluate`` with
    ``equinox.filter_grad``. The discretisation (sizes, nodes, kernels) stays as planned:
    re-plan when parameters move far enough to change it.
    """

    materials: tuple[Material | AnisotropicMaterial, ...]
    parts: tuple[MaterialPlan, ...]
    n_queries: int = eqx.field(static=True)
    tol: float = eqx.field(static=True)
    pixels: Int[Array, " Q"] | None = None
    resolution: tuple[int, int] | None = eqx.field(static=True, default=None)

    @_plain_method
    def evaluate(self, materials: tuple[Material | AnisotropicMaterial, ...] | None = None) -> Float[Array, " Q"]:
        """ρ at every query (jit-compiled)."""
        materials = self.materials if materials is None else tuple(materials)
        if len(materials) != len(self.materials):
            raise InvalidInputError(f"expected {len(self.materials)} materials; got {len(materials)}.")
        return _evaluate(self.parts, materials, self.n_queries)

    def image(self, values: Float[Array, " Q"] | None = None) -> Float[Array, "rows cols"]:
        """The values scattered into the camera image (pixels without a query are 0)."""
        if self.pixels is None or self.resolution is None:
            raise InvalidInputError("this plan has no camera; image() needs a scene from camera_scene().")
        values = self.evaluate() if values is None else values
        rows, cols = self.resolution
        return jnp.zeros(rows * cols, values.dtype).at[self.pixels].set(values).reshape(rows, cols)

    @property
    def predicted_error(self) -> float:
        """The largest predicted error of any material, relative to its lobe's peak."""
        return max(p.predicted_error for p in self.parts)

    @property
    def predicted_cost(self) -> float:
        """Predicted work of :meth:`evaluate` in relative cost units, not seconds
        (:mod:`brdfscale.scene._cost`: one unit per multiply-add, 20 per transcendental
        evaluation, plus the fixed cost of a call). It ranks alternatives;
        experiments/bench_planner.py measures the seconds per unit on its machine."""
        return _cost.CALL_UNITS + sum(p.predicted_cost for p in self.parts)

    def _show_items(self):
        items = [("queries", self.n_queries), ("tol", self.tol)]
        if self.resolution is not None:
            items.append(("camera", f"{self.resolution[0]}×{self.resolution[1]} px"))
        items += [("predicted_error", self.predicted_error), ("predicted_cost", self.predicted_cost)]
        parts = "; ".join(f"material {p.material}: {p.path}, {p.queries} queries" for p in self.parts)
        return items + [("parts" if len(self.parts) > 1 else "part", parts)]

    def _show_tables(self):
        rows = [
            (
                p.material,
                type(self.materials[p.material]).__name__,
                p.path,
                p.queries,
                p.predicted_error,
                p.predicted_cost,
                p.reason,
            )
            for p in self.parts
        ]
        return [
            Table(
                "parts (one per material)",
                ("material", "kind", "path", "queries", "predicted error", "predicted cost", "why"),
                rows,
            )
        ]

    def plot(self, **options):
        """A figure of what is computed where: :func:`brdfscale.plot.plan` (options as there);
        returns a ``matplotlib.figure.Figure``."""
        from .._figures import draw

        return draw("plan", self, **options)

    def explain(self) -> str:
        """What will be computed and why, with the predicted cost and error."""
        lines = [f"Plan for {self.n_queries} queries, error target {self.tol:.3g} (relative to each lobe's peak):"]
        for p in self.parts:
            material = self.materials[p.material]
            keys = "(pair, Γ∞, μ)" if p.path == "so3" else "(u, μ)"
            lines.append(
                f"- material {p.material} ({type(material.lobe).__name__} lobe at μ0 = {float(material.mu0):.4g}, "
                f"{type(material.law).__name__} statistics): {len(p.rows)} queries, "
                f"{len(np.unique(np.asarray(p.inverse)))} distinct {keys}"
            )
            lines.append(f"    path: {p.path} — {p.reason}")
            lines.append(f"    {p.details}")
            lines.append(f"    predicted error ≤ {p.predicted_error:.2g}, predicted cost {p.predicted_cost:.3g} units")
        lines.append(
            f"Total: predicted error ≤ {self.predicted_error:.2g}, predicted cost {self.predicted_cost:.3g} units "
            "(relative units that rank the paths, not seconds; see brdfscale.scene._cost)."
        )
        return "\n".join(lines)


def _evaluate(parts, materials, n):
    """One compiled program per material: its step, scattered into the queries' order (the
    materials' query rows are disjoint, so the programs' outputs add up exactly). Compiled as
    one program, XLA:CPU's fusion choices for one material's step changed with the other's and
    the whole ran much slower than its parts together (profiled on the receding-plane workload
    of experiments/bench_planner.py); a plan with one material is one program, as before.
    Under a caller's ``jax.jit`` the programs are traced into the caller's."""
    return functools.reduce(jnp.add, [_evaluate_part(p, materials[p.material], n) for p in parts])


@eqx.filter_jit
def _evaluate_part(part, material, n):
    values = part(material)
    return jnp.zeros(n, values.dtype).at[part.rows].set(values)
