"""Many materials fitted at once: one compiled least-squares program per bucket, divided over the devices.

A Python loop of :func:`fitting.fit` over a library compiles a new solve for nearly every
material: the compiled program depends on the data's shapes (how many distinct points each
scale has) and on its layout. :func:`fit_many` instead

1. reduces every material to its residual rows (:class:`fitting._problem.Rows`: the model, the
   scales, the distinct points with their weights, the prior box — seed Eq. 4.4 evaluated at
   the points of :meth:`Dataset.points`);
2. **buckets** the materials by what the program's structure depends on — the model's static
   structure (its kind, families, fixed values; a :class:`~fitting.NonParametricModel`'s knots
   and grid), the number of scales and of θ coordinates — and by the number of distinct points
   per scale, first rounded up to the ladder ``8·{1, 1.5, 2, 3, 4, 6, …}`` (:func:`bucket_points`:
   at most 50 % padding), then adjacent rungs merged wherever computing their extra padding
   costs less than compiling one more program (:func:`plan`, an exact dynamic programme over
   the rungs with the exchange rate ``compile_rows``). Padded rows carry zero weight, which adds
   exactly 0 to every residual, χ² and ``JᵀJ``; the plan (:func:`explain_plan`) states the
   buckets and the padding fraction;
3. stacks each bucket's materials × starts along one axis, pads that axis to a whole
   ``batch`` (repeating the bucket's first material; the copies' results are dropped) rounded
   up to whole groups of ``lanes`` on every device, and runs Levenberg–Marquardt (or the chosen
   optimistix solver) over it in **one compiled program**, ``lanes`` solves at a time
   (:func:`select_lanes`): on a CPU one solve at a time (a ``jax.lax.map``: each solve takes
   its own iterations, and this program is traced and compiled in about half the time of the
   vmapped one), on an accelerator all of them **vmapped** in lock-step (a finished solve keeps its
   state while the others iterate) — either way each material's path is the one it would
   take alone;
4. **divides** that axis over the devices (``jax.devices()`` by default) by the one mechanism
   of :mod:`fitting._devices`: each device gets a contiguous, equal slice and runs the same
   program on it by itself, one dispatch per device (the devices compute at once where JAX
   dispatches asynchronously, as on GPUs; in turn on CPU devices); no collective is needed:
   each device stops when its own slice has converged (that module says why not XLA's SPMD
   partitioning or ``shard_map``). Each device compiles the bucket's program, once per process;
5. hands each material's starts to the same analysis as :func:`fitting.fit` (best start,
   Laplace covariance and identifiability by :mod:`brdfscale.laplace`), then evaluates the
   quantities and ratios of the bucket's materials at their optima and Laplace draws in one
   more, vmapped program (:func:`fitting._analysis.results_of_starts`).

The result of each material equals that of ``fitting.fit(model, data)`` with the same
options to the solver's tolerance: the starts are the same (same seed), the solver is the
same; only the convergence test's root-mean-square runs over the padded rows too (zeros), so a
solve may stop one step earlier or later (tests/test_batch.py checks θ̂ to 1e-3 of the
Laplace σ, χ² to 1e-6 relative, and every reported σ).
"""

import dataclasses
import math
import sys

import equinox as eqx
import jax
import numpy as np

from brdfscale import InvalidInputError
from brdfscale.checks import integer
from brdfscale.choices import FIT
from brdfscale.show import progress_bar

from ._analysis import results_of_starts
from ._data import Dataset, PointData
from ._devices import device_list as _devices, joined, on_devices, split
from ._fit import FitOptions, resolve_starts
from ._model import AbstractModel
from ._problem import check_pair, Problem, Rows, stack_trees, starting_points
from ._solve import solve_rows


__all__ = ["COMPILE_ROWS", "BatchPlan", "bucket_points", "explain_plan", "fit_many"]


def _rung(n: int, smallest: int) -> int:
    """The smallest of ``smallest·2^k`` and ``smallest·3·2^(k−1)`` (k ≥ 0; the rungs 1, 1.5, 2, 3, 4,
    6, … times ``smallest``) that is ≥ ``n``: at most 1.5 × ``n`` for ``n`` above ``smallest``."""
    size = smallest
    while size < n:
        if size * 3 % 2 == 0 and size * 3 // 2 >= n:
            return size * 3 // 2
        size *= 2
    return size


def bucket_points(n: int) -> int:
    """The padded number of points per scale for a material with ``n``: the smallest rung of
    ``8, 12, 16, 24, 32, 48, …`` (8·2^k and 12·2^k) that holds it — at most 1.5 × ``n``
    (above 8)."""
    return _rung(max(int(n), 1), 8)


def bucket_batch(n: int, batch: int) -> int:
    """The padded number of materials of a program run holding ``n`` (≤ ``batch``): the rung
    of ``1, 2, 3, 4, 6, 8, 12, …`` at or above ``n``, at most ``batch`` — so runs of different
    libraries and tasks share compiled programs (:func:`plan` rounds the solves up to whole devices)."""
    return min(_rung(n, 1), batch)


@dataclasses.dataclass(frozen=True)
class Bucket:
    """One compiled program of :func:`fit_many`: the ``materials`` (their indices), ``points``
    (padded points per scale), ``scales``, ``parameters``, ``batch`` (the padded number of
    materials of the program run, :func:`bucket_batch`), ``solves`` (materials × starts, rounded
    up to whole groups of ``lanes`` per device) and ``lanes`` (the solves advanced together on a
    device, :func:`select_lanes`)."""

    materials: tuple
    points: int
    scales: int
    parameters: int
    batch: int
    solves: int
    lanes: int


@dataclasses.dataclass(frozen=True)
class BatchPlan:
    """How :func:`fit_many` divides a library: the buckets (:class:`Bucket`, one compiled program
    each), the padded sizes and the padding's cost."""

    buckets: tuple
    devices: int
    starts: int
    rows_used: int
    rows_padded: int

    @property
    def padding(self) -> float:
        """The fraction of the computed rows that is padding (0 = none)."""
        return 1.0 - self.rows_used / self.rows_padded if self.rows_padded else 0.0

    def explain(self) -> str:
        lines = [
            (
                f"{sum(len(b.materials) for b in self.buckets)} materials in {len(self.buckets)} bucket(s) on "
                f"{self.devices} device(s), {self.starts} start(s) each; padding {100 * self.padding:.0f} % of the rows"
            )
        ]
        for b in self.buckets:
            per_device = b.solves // self.devices
            how = (
                "all in lock-step (vmapped)"
                if b.lanes >= per_device
                else "one solve at a time"
                if b.lanes == 1
                else f"{b.lanes} at a time"
            )
            lines.append(
                f"  {len(b.materials)} × ({b.scales} scales × {b.points} points, {b.parameters} "
                f"parameters): a program of {b.solves} solves ({b.batch} materials × {self.starts} starts)"
                f", {per_device} per device, {how}"
            )
        return "\n".join(lines)


def _key(rows: Rows, n_points: int) -> tuple:
    # what a compiled program depends on: the model's static structure (its treedef holds the
    # static fields), the dynamic leaves' shapes, the number of scales, the θ size, the padded points
    dynamic, static = eqx.partition(rows.model, eqx.is_array)
    shapes = tuple((x.shape, str(x.dtype)) for x in jax.tree.leaves(dynamic))
    return (
        jax.tree.structure(static),
        jax.tree.structure(dynamic),
        shapes,
        int(rows.scales.shape[0]),
        int(rows.lower.shape[0]),
        int(rows.model.penalty(rows.lower).shape[0]),
        bucket_points(n_points),
    )


def _pad_points(points: PointData, n: int) -> PointData:
    extra = n - points.mean.shape[1]
    # NumPy: an eager jnp.pad would compile a program for every material's shape
    return PointData(
        points=np.pad(np.asarray(points.points), ((0, 0), (0, extra), (0, 0))),
        mean=np.pad(np.asarray(points.mean), ((0, 0), (0, extra))),
        weight=np.pad(np.asarray(points.weight), ((0, 0), (0, extra))),
        chi2_offset=points.chi2_offset,
    )


@eqx.filter_jit
def _solve_batch(rows, y0, solver, max_steps, lanes):
    """:func:`fitting._solve.solve_rows` over the leading axis of ``rows`` and ``y0``, ``lanes``
    solves at a time: one compiled program per bucket shape (and device) for every (material,
    start) of the batch. ``lanes`` ≥ the axis: one ``jax.vmap`` of the solve (all in lock-step);
    fewer: a ``jax.lax.map`` over groups of ``lanes`` (each group vmapped; ``lanes == 1``: each
    solve by itself, its own iterations) — the axis is a whole number of groups (:func:`plan`)."""

    def one(r, y):
        return solve_rows(r, y, solver, max_steps)

    if lanes >= y0.shape[0]:
        return jax.vmap(one)(rows, y0)
    arrays, static = eqx.partition(rows, eqx.is_array)  # lax.map carries arrays only
    return jax.lax.map(
        lambda a: one(eqx.combine(a[0], static), a[1]), (arrays, y0), batch_size=None if lanes == 1 else lanes
    )


def select_lanes(devices, lanes=None) -> int:
    """How many solves :func:`fit_many` advances together on each device: ``lanes`` if given
    (an integer ≥ 1, or ``"all"``), else by the devices' platform — **1 on CPUs** (each solve
    runs by itself, its own iterations; its program is also traced and compiled in about half
    the time of the vmapped one — both measured by ``experiments/bench_library.py``: the
    ``lanes`` rows of docs/library.md's table), **all** of a device's slice elsewhere (one
    ``jax.vmap``: the solves fill the accelerator's parallel units; a finished solve waits for
    the slowest of its group). ``sys.maxsize`` stands for "all"."""
    if lanes is None:
        return 1 if all(d.platform == "cpu" for d in devices) else sys.maxsize
    if isinstance(lanes, str) and lanes == "all":
        return sys.maxsize
    try:
        return integer(lanes, "lanes", 1)
    except InvalidInputError:
        raise InvalidInputError(
            f"lanes must be None (by platform: 1 on CPUs, all on accelerators), an integer ≥ 1 or 'all'; got {lanes!r}."
        ) from None


def _problems(models, datasets) -> list:
    """The :class:`Problem` of every (model, dataset) pair; InvalidInputError naming the material."""
    if isinstance(datasets, Dataset):
        raise InvalidInputError(
            "fit_many(models, datasets) takes a sequence of datasets; for one dataset use fitting.fit(model, data)."
        )
    try:
        datasets = list(datasets)
    except TypeError:
        raise InvalidInputError(
            f"datasets must be a sequence of fitting.Dataset; got {type(datasets).__name__}."
        ) from None
    if not datasets:
        raise InvalidInputError("fit_many needs at least one dataset.")
    if isinstance(models, AbstractModel):
        models = [models] * len(datasets)
    else:
        try:
            models = list(models)
        except TypeError:
            raise InvalidInputError(
                "models must be one fitting model (used for every dataset) or a sequence of "
                f"models, one per dataset; got {type(models).__name__}."
            ) from None
        if len(models) != len(datasets):
            raise InvalidInputError(
                f"models and datasets must pair up: got {len(models)} models for "
                f"{len(datasets)} datasets (or pass one model for all)."
            )
    problems = []
    for i, (model, data) in enumerate(zip(models, datasets)):
        check_pair(model, data, f"fit_many: material {i}")
        try:
            problems.append(Problem(model, data))
        except InvalidInputError as err:
            raise InvalidInputError(f"fit_many: material {i}: {err}") from None
    return problems


#: Padded residual rows (summed over starts) whose solve is taken to cost as much as compiling
#: one more program. ``experiments/bench_library.py`` measures the rate on its machine
#: (``compile_rows_measured``: one bucket's compilation over a warm rerun's seconds per padded
#: row, docs/library.md); on its 2-core CPU the measurement is of the same order as this value,
#: which is kept lower: a compilation is paid once per process (once ever with the command's
#: persistent cache), padding on every run.
COMPILE_ROWS = 400_000


def plan(
    problems, starts: int, batch: int, n_devices: int, compile_rows: int = COMPILE_ROWS, lanes: int = 1
) -> BatchPlan:
    """The buckets of :func:`fit_many` for these problems (module docstring, step 2).

    Materials of one structure are first grouped by their rung of points per scale
    (:func:`bucket_points`); adjacent rungs are then merged where computing the extra padding
    costs less than compiling another program — the partition of the sorted rungs that
    minimises ``compile_rows × (programs) + (padded rows)``, found exactly by dynamic
    programming (``compile_rows = 0`` keeps every rung apart: padding ≤ 50 % of the rows).
    Each program run's solves are rounded up to whole groups of ``lanes`` on every device
    (:func:`select_lanes`; a bucket's ``lanes`` is at most its solves per device)."""
    groups: dict = {}
    used = 0
    for i, problem in enumerate(problems):
        rows = problem.rows()
        n = int(rows.points.mean.shape[1])
        used += n * int(rows.scales.shape[0]) * starts
        key = _key(rows, n)
        groups.setdefault(key[:-1], {}).setdefault(key[-1], []).append(i)
    buckets, padded = [], 0
    for key, by_rung in groups.items():
        scales = key[3]
        rungs = sorted(by_rung)
        count = [len(by_rung[r]) for r in rungs]
        # best[j]: least cost of rungs[:j]; a group rungs[i:j] is padded to rungs[j − 1]
        best, cut = [0.0] + [math.inf] * len(rungs), [0] * (len(rungs) + 1)
        for j in range(1, len(rungs) + 1):
            for i in range(j):
                cost = best[i] + compile_rows + rungs[j - 1] * scales * starts * sum(count[i:j])
                if cost < best[j]:
                    best[j], cut[j] = cost, i
        spans, j = [], len(rungs)
        while j > 0:
            spans.append((cut[j], j))
            j = cut[j]
        for i, j in reversed(spans):
            members = [m for r in rungs[i:j] for m in by_rung[r]]
            points = rungs[j - 1]
            for k in range(0, len(members), batch):
                chunk = members[k : k + batch]
                size = bucket_batch(len(chunk), batch)
                per_device = -(-size * starts // n_devices)
                group = min(lanes, per_device)
                solves = -(-per_device // group) * group * n_devices
                buckets.append(
                    Bucket(
                        materials=tuple(chunk),
                        points=points,
                        scales=scales,
                        parameters=key[4],
                        batch=size,
                        solves=solves,
                        lanes=group,
                    )
                )
                padded += solves * points * scales
    return BatchPlan(buckets=tuple(buckets), devices=n_devices, starts=starts, rows_used=used, rows_padded=padded)


def fit_many(
    models,
    datasets,
    *,
    batch: int = 64,
    devices=None,
    solver=FIT.solver,
    starts: int | str = FIT.starts,
    spread: float = FIT.spread,
    seed: int = FIT.seed,
    max_steps: int = FIT.max_steps,
    rtol: float = FIT.rtol,
    atol: float = FIT.atol,
    undetermined_std: float = FIT.undetermined_std,
    compile_rows: int = COMPILE_ROWS,
    lanes=None,
    progress: bool = False,
    errors: str = "raise",
) -> list:
    """Fit many materials at once: :func:`fitting.fit` for every ``(model, data)`` pair, in
    one compiled program per bucket, divided over the devices (module docstring).

    Args:
        models: one fitting model for every dataset, or a sequence of models, one per dataset.
        datasets: a sequence of :class:`~fitting.Dataset` (any sizes, masks, image counts).
        batch: at most this many materials per compiled program run (≥ 1; default 64). A
            bucket with more runs the same program several times; one with fewer is padded
            only to a whole number of solves per device.
        devices: ``None`` (every device of ``jax.devices()``), a count (the first ones), or a
            list of ``jax.Device``; the batch axis is divided over them (module docstring, step 4).
        solver, starts, spread, seed, max_steps, rtol, atol, undetermined_std: as for
            :func:`fitting.fit`, for every material (the seed is each material's, so each
            material gets the starts ``fit`` would give it; with ``"auto"`` and models of different
            preferences one count and one solver serve them all: the most starts any prefers, and
            ``"lm"`` unless every model prefers the same solver — :func:`fitting.resolve_starts`,
            :func:`fitting.resolve_solver`).
        compile_rows: the bucketing's exchange rate (:func:`plan`): padded rows worth one
            more compiled program (default :data:`COMPILE_ROWS`, of the order measured on a 2-core
            CPU; on an accelerator a solve row is cheaper, so larger values merge more); 0 keeps every
            rung of :func:`bucket_points` apart.
        lanes: how many solves each device advances together (:func:`select_lanes`): ``None``
            (default) picks by platform — 1 on CPUs (a ``lax.map``: each solve its own
            iterations), all of the device's slice on accelerators (one ``vmap``); an integer
            ≥ 1 sets it (a group of ``lanes`` runs vmapped, the groups in turn), ``"all"``
            vmaps the whole slice. The results do not depend on it beyond rounding.
        progress: a progress bar over the materials.
        errors: ``"raise"`` (default): a material whose every start ends with a non-finite χ²
            raises, as :func:`fitting.fit` does; ``"return"``: its entry in the result is the
            :class:`~brdfscale.InvalidInputError` instead, and the others are kept.

    Returns:
        A list of :class:`FitResult`, in the order of ``datasets``.

    Raises:
        InvalidInputError: the arguments of :func:`fitting.fit` for any material (naming its
            index), models and datasets that do not pair up, ``batch`` not an integer ≥ 1,
            ``devices`` not as above, ``lanes`` not ``None``, an integer ≥ 1 or ``"all"``, ``errors`` not
            ``"raise"``/``"return"``.
    """
    problems = _problems(models, datasets)
    options = FitOptions.for_models(
        [p.model for p in problems],
        solver=solver,
        starts=starts,
        max_steps=max_steps,
        spread=spread,
        seed=seed,
        rtol=rtol,
        atol=atol,
        undetermined_std=undetermined_std,
    )
    batch = integer(batch, "batch", 1)
    if errors not in ("raise", "return"):
        raise InvalidInputError(f"errors must be 'raise' or 'return'; got {errors!r}.")
    device_list = _devices(devices)
    layout = plan(
        problems,
        options.starts,
        batch,
        len(device_list),
        integer(compile_rows, "compile_rows", 0),
        select_lanes(device_list, lanes),
    )
    optimiser = options.optimiser()
    results: list = [None] * len(problems)
    S = options.starts
    with progress_bar(enabled=progress, total=len(problems), desc="fit_many", unit="material") as bar:
        for bucket in layout.buckets:
            members = bucket.materials
            rows = [problems[i].rows() for i in members]
            rows = [dataclasses.replace(r, points=_pad_points(r.points, bucket.points)) for r in rows]
            y0 = [np.asarray(starting_points(problems[i], options)) for i in members]
            # materials × starts along one axis, padded with copies of the first material
            flat_rows = [r for r in rows for _ in range(S)]
            flat_y0 = [y for ys in y0 for y in ys]
            extra = bucket.solves - len(flat_rows)
            flat_rows += [flat_rows[0]] * extra
            flat_y0 += [flat_y0[0]] * extra
            # _solve_batch looked up at each call (tests/test_batch.py records the devices it runs on)
            solved = joined(
                on_devices(
                    lambda r, y, lanes=bucket.lanes: _solve_batch(r, y, optimiser, options.max_steps, lanes),
                    (
                        split(stack_trees(flat_rows), device_list),
                        split(np.stack(flat_y0).astype(np.float64), device_list),
                    ),
                    device_list,
                )
            )
            values, codes, steps, chi2s, jacobians = (  # (material, start, …), the padding dropped
                a[: len(members) * S].reshape(len(members), S, *a.shape[1:]) for a in solved
            )
            done = results_of_starts([problems[i] for i in members], values, codes, steps, chi2s, jacobians, options)
            for i, result in zip(members, done):
                if isinstance(result, InvalidInputError) and errors == "raise":
                    raise InvalidInputError(f"fit_many: material {i}: {result}") from None
                results[i] = result
                bar.update(1)
    return results


def explain_plan(
    models,
    datasets,
    *,
    batch: int = 64,
    devices=None,
    starts: int | str = FIT.starts,
    compile_rows: int = COMPILE_ROWS,
    lanes=None,
) -> BatchPlan:
    """The :class:`BatchPlan` :func:`fit_many` would follow for these arguments (nothing is
    fitted); ``plan.explain()`` says it in words."""
    problems = _problems(models, datasets)
    device_list = _devices(devices)
    return plan(
        problems,
        integer(resolve_starts(starts, [p.model for p in problems]), "starts", 1),
        integer(batch, "batch", 1),
        len(device_list),
        integer(compile_rows, "compile_rows", 0),
        select_lanes(device_list, lanes),
    )
