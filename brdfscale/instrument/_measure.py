"""The virtual gonioreflectometer: spots of size μ aligned to their mean planes, lobe images in half-slope offsets.

**What one image is.** For a scale μ and an incident direction ``i`` (given in the frame of the spot, as a real
instrument gives it after aligning the sample), light falls on *spots*: the whole μ × μ windows of the field that
:func:`brdfscale.synth.facet_slopes` tiles it with (the facets of :func:`brdfscale.synth.gonioreflectometer`). Each
spot is aligned to its own mean plane — rotated by the smallest rotation that takes the mean normal ``(m_f, 1)`` of
the window (its facet slope ``m_f``) to the instrument's z axis — and lit uniformly over the window's horizontal
footprint. Each ray picks a spot at random (uniformly among the spots of the scale), a point in it, and is followed
through the surface by :func:`._trace.trace` (shadowing, masking, up to ``bounces`` reflections). A path that leaves
the surface into direction ``o`` above the spot's mean plane is detected at the half-vector slope
``u = m(normalise(i + o))`` of the spot frame (``m∞ = 0`` there: the offsets ``u = m_s − m∞`` of
docs/conventions.md §6).

**The convention.** The image is the BRDF the instrument measures converted to the measurement sets' lobe form
``ρ = A·g(u)/(4 cosθ_o cos⁴θ_h)`` (docs/conventions.md §1): ``image(u) = 4 cosθ_o cos⁴θ_h ρ(i, o)``. With ``f(o)`` the
reflected power per unit solid angle per unit power falling on the spots, ``ρ = f cosθ_i / cosθ_o`` and
``dω_o = 4 (i·h) cos³θ_h d²u``, so each detected path of throughput ``w`` deposits

    w · c / (N h²),     c = cosθ_i cosθ_h / (i·h) = i_z / (i_z + u·i_xy),

on the node nearest to ``u`` (``binning="nearest"``, the default: the node's detector cell of ``h × h`` around it;
``binning="bilinear"`` shares it among the four nodes around ``u`` with the cloud-in-cell weights of
:class:`brdfscale.stats.SlopeHistogram`, the binning of :func:`brdfscale.synth.gonioreflectometer`), ``h`` the node
pitch and ``N`` the *lit* rays: those whose
light met the surface, and those that would have to come from below the global plane (a spot tilted further than
the incidence allows), which the sample's body blocks (lit and lost, ``from_below``). Light that meets no surface —
through an unmeasured hole, past a measured field's edge — is left out (``unmeasured``). For mirror facets
without masking and shadowing this is exactly the density of the facets' slope offsets per unit area, the
``"nearly_flat"`` image of :func:`brdfscale.synth.gonioreflectometer` (the light a facet intercepts,
``∝ 1 + m·i_xy/i_z``, is divided out by ``c``); tests/test_instrument.py compares the two.

**The detector.** Node ``(j, k)`` is the half-slope offset ``u = (x_k, y_j)``, ``x, y = linspace(−a, a, n)``; its cell
of ``h × h`` in half-slope offsets is the detector solid angle ``Ω(u) = 4 (i·h) cos³θ_h h²`` (in the spot frame),
recorded in the metadata at ``u = 0`` for each incident direction. With nearest-node binning a node's value is the
image averaged over its cell (``g + (h²/24)∇²g`` to second order), every path counts in one node only, and the
Monte Carlo errors of neighbouring nodes are independent (up to the −1/N of a multinomial), as the fits' χ² and
their residual test assume. Bilinear shares blur the image with the tent (``g + (h²/12)∇²g``) and correlate
neighbouring nodes' errors: for a smooth image the lag-1 correlation along a row or column is 1/4 (per axis a node
collects shares ``1 − f`` from the two cells beside it and shares one cell with its neighbour, which gets ``f``;
f uniform: ``E[(1 − f)f]/(2E[(1 − f)²]) = (1/6)/(2/3)``), which the fits' adequacy check (docs/fitting.md, lag-1
autocorrelation above 0.1) reads as structure
(tests/test_instrument.py::test_nearest_node_binning_leaves_neighbouring_errors_independent measures both).

**σ.** The rays of an image are split into ``batches`` batches with independent random numbers; each batch is an
unbiased estimate of the same image, and σ is the standard error of their ratio estimate,
``σ² = B/(B−1) · Σ_b (C_b − image·N_b)² / (Σ_b N_b)²`` (``C_b`` the batch's node sums per unit slope area, ``N_b``
its lit rays), floored at ``1/(N h²)`` — what one ray of unit weight deposits on a node (a node no
ray reached reads 0 ± that, the one-count floor of Poisson statistics). It is the Monte Carlo error of the average
over the spots (the random choice of spot per ray included), not the spread of the surface's realisations.

**Determinism and tasks.** Batch ``b`` of image ``(scale s, incident k)`` draws its random numbers from
``numpy.random.SeedSequence(seed, spawn_key=(0, s, k, b))`` and is traced on its own, and the batches are summed in
a fixed order, so a measurement is bit-identical for a seed whatever the split into :class:`Task` s
(:meth:`Measurement.tasks`) and the order they run in (on one Mitsuba variant; variants differ in rounding) — in this
process or as Ray tasks (:meth:`Measurement.measure` with ``executor="ray"``, through :mod:`brdfscale._cluster`, the
mechanism :func:`brdfscale.library.fit_library` runs on; tests/test_instrument.py checks the two equal).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Sequence

import numpy as np
from jaxtyping import ArrayLike, Float

from .. import lobes, stats, synth
from .._choices import BINNINGS, EXECUTORS, MESHES
from .._errors import BrdfscaleError, InvalidInputError, LobeCutWarning
from .._measurement import LobeImage, MeasurementSet
from .._show import progress_bar
from .._validation import integer, real, real_array
from ..geometry import validate_directions
from ..stats import SlopeHistogram
from ..synth import HeightField
from . import _mesh, _micro, _trace


DEFAULT_RAYS = 100_000
"""Rays per image (per scale and incident direction) unless ``rays=`` says otherwise."""
DEFAULT_BATCHES = 32
"""Batches per image: the independent estimates σ comes from (σ itself is then known to about 1/√(2·31) = 13 %)."""
MAX_BOUNCES = 64
"""The most reflections a path may take."""


@dataclasses.dataclass(frozen=True)
class Task:
    """A piece of a measurement: the batches ``(scale index, incident index, batch index)`` it traces, in order."""

    batches: tuple[tuple[int, int, int], ...]


@dataclasses.dataclass(frozen=True)
class TaskResult:
    """A task's partial sums, one entry per batch (in the task's order): node sums ``counts`` (n, n) of ``w·c``,
    the ``hit`` (lit) rays each batch's image is normalised by, and tallies (escaped, detected and lost weight, rays
    by fate); with
    ``Measurement.run(task, quads=True)`` also ``quads``, the pixel quad ``(row, col)`` of every surface hit (M, 2)."""

    batches: tuple[tuple[int, int, int], ...]
    counts: tuple[np.ndarray, ...]
    hit: tuple[int, ...]
    tallies: tuple[dict, ...]
    quads: np.ndarray | None = None


def _check_seed(seed) -> int:
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInputError(
            f"seed must be an integer ≥ 0 (a measurement is reproducible from it); got {type(seed).__name__} {seed!r}."
        )
    return int(seed)


def _check_variant(variant) -> str | None:
    if variant is not None and not isinstance(variant, str):
        raise InvalidInputError(
            f"variant must be None (the first Mitsuba variant that runs here) or a variant's name such as "
            f"'llvm_ad_rgb' or 'scalar_rgb'; got {type(variant).__name__}."
        )
    return variant


class Measurement:
    """A planned measurement: :func:`measure`'s arguments checked, split into tasks that can run anywhere.

    ``Measurement(field, scales, incident, **options)`` takes :func:`measure`'s arguments (less ``progress``).
    :meth:`tasks` splits it into :class:`Task` s of whole batches; :meth:`run` traces one (in this process; the
    object and its tasks pickle, so a cluster can run them — the scene is built once per process);
    :meth:`combine` sums their results into the :class:`brdfscale.MeasurementSet` — the same, bit for bit, whatever
    the split. :meth:`measure` does all three here.
    """

    def __init__(
        self,
        field: HeightField,
        scales,
        incident: Float[ArrayLike, "*k 3"] | Sequence[float] | Sequence[Sequence[float]],
        *,
        extent: float,
        pixels: int = 65,
        micro=None,
        rays: int = DEFAULT_RAYS,
        bounces: int = 1,
        spots: int | None = None,
        batches: int = DEFAULT_BATCHES,
        fresnel=None,
        surface: str = MESHES.default,
        pad: int | None = None,
        binning: str = BINNINGS.default,
        seed: int = 0,
        variant: str | None = None,
    ):
        self.field = _mesh.check_field(field)
        a = real_array(scales, "scales")
        if a.ndim > 1 or a.size == 0:
            raise InvalidInputError(f"scales must be a facet size or a 1-D sequence of them; got shape {a.shape}.")
        self.scales = [float(mu) for mu in np.atleast_1d(a)]
        self.blocks = [field.block(mu) for mu in self.scales]
        directions = np.atleast_2d(real_array(incident, "incident"))
        validate_directions(directions, "incident")
        if directions.ndim != 2:
            raise InvalidInputError(f"incident must have shape (3,) or (k, 3); got {np.shape(incident)}.")
        self.incident = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
        self.extent = real(extent, "extent", minimum=0, strict=True)
        self.pixels = integer(pixels, "pixels", 2)
        SlopeHistogram(self.extent, self.pixels)  # refuses a histogram above its memory bound now
        self.micro = _micro.resolve(field.micro if micro is None else micro, fresnel)
        self.rays = integer(rays, "rays", 2)
        self.bounces = integer(bounces, "bounces", 1)
        if self.bounces > MAX_BOUNCES:
            raise InvalidInputError(f"bounces must be an integer from 1 to {MAX_BOUNCES}; got {bounces!r}.")
        self.batches = integer(batches, "batches", 2)
        if self.rays < self.batches:
            raise InvalidInputError(f"rays must be at least batches = {self.batches}; got rays={self.rays}.")
        self.spots = None if spots is None else integer(spots, "spots", 1)
        self.surface = MESHES.check(surface)
        self.pad = _mesh.default_pad(field, self.surface) if pad is None else _mesh.check_pad(field, pad)
        _mesh.check_mesh_size(field, self.surface, self.pad)
        self.binning = BINNINGS.check(binning)
        self.seed = _check_seed(seed)
        self.variant = _check_variant(variant)
        self._spots = [self._spot_set(s) for s in range(len(self.scales))]

    # -- geometry of the spots -----------------------------------------------------------------
    def _spot_set(self, s: int) -> dict:
        """The spots of scale ``s``: their windows ``(J, K)``, mean-plane slopes and heights (pixel units)."""
        field, mu, (by, bx) = self.field, self.scales[s], self.blocks[s]
        slopes = synth.facet_slopes(field, mu)  # (R, C, 2), NaN where a window touches an unmeasured pixel
        valid = np.isfinite(slopes).all(axis=-1)
        J, K = np.nonzero(valid)
        if len(J) == 0:
            raise InvalidInputError(f"no spot of mu={mu:g} lies wholly on measured pixels; use a smaller scale.")
        if self.spots is not None and self.spots < len(J):
            rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(1, s)))
            keep = np.sort(rng.choice(len(J), self.spots, replace=False))
            J, K = J[keep], K[keep]
        dx, dy = field.spacing
        h = (field.heights - self._mean_height()) / dx
        nby, nbx = slopes.shape[:2]
        # the mean height of each window's nodes: the spot's mean plane passes through it at the window's centre
        height = h[: nby * by, : nbx * bx].reshape(nby, by, nbx, bx).mean(axis=(1, 3))[J, K]
        # per spot 24 bytes of float64 and 8 of int32 (a 2048² field at μ = 1 px: 134 MB); origins, centres and
        # rotations are made per ray
        return {
            "J": J.astype(np.int32),
            "K": K.astype(np.int32),
            "height": height,
            "slope": slopes[J, K].astype(np.float64),
            "count": int(len(J)),
            "windows": int(valid.sum()),
        }

    def _geometry(self, s: int, spot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per ray of scale ``s`` aimed at ``spot``: its window's corner and centre (x, y in mesh units) and size."""
        (by, bx), ratio = self.blocks[s], self.field.spacing[1] / self.field.spacing[0]
        spots, shift = self._spots[s], np.array(_mesh.centre(self.field))
        corner = np.stack((spots["K"][spot] * bx, spots["J"][spot] * by * ratio), axis=-1) - shift
        size = np.array([bx, by * ratio], np.float64)
        return corner, corner + (size - np.array([1.0, ratio])) / 2, size

    @functools.cached_property
    def _relief(self) -> tuple[float, float]:
        h = (self.field.heights - self._mean_height()) / self.field.spacing[0]
        return float(h.min()), float(h.max())

    def _mean_height(self) -> float:
        f = self.field
        return float(np.mean(f.heights if f.mask is None else f.heights[f.mask]))

    # -- tasks ---------------------------------------------------------------------------------
    @property
    def images(self) -> list[tuple[int, int]]:
        """``(scale index, incident index)`` of every image, scales outermost (synth.gonioreflectometer's order)."""
        return [(s, k) for s in range(len(self.scales)) for k in range(len(self.incident))]

    def tasks(self, batches_per_task: int | None = None) -> tuple[Task, ...]:
        """The measurement as tasks of ``batches_per_task`` consecutive batches (default: one task per image)."""
        per = self.batches if batches_per_task is None else integer(batches_per_task, "batches_per_task", 1)
        every = [(s, k, b) for s, k in self.images for b in range(self.batches)]
        return tuple(Task(tuple(every[i : i + per])) for i in range(0, len(every), per))

    def _rays_in(self, b: int) -> int:
        return self.rays // self.batches + (b < self.rays % self.batches)

    # -- tracing -------------------------------------------------------------------------------
    def _scene(self):
        """(mi, scene, bsdf), built once per process and measurement (not pickled); Mitsuba's process-wide variant is
        set back to the one the scene was built in (through brdfscale._mitsuba) if something changed it since."""
        from .. import _mitsuba

        scene = self.__dict__.get("_scene_cache")
        if scene is None:
            mi = _mitsuba.mitsuba(self.variant)
            shape = _mesh.mesh(self.field, surface=self.surface, pad=self.pad, variant=mi.variant())
            scene = (
                mi,
                mi.load_dict({"type": "scene", "surface": shape}),
                mi.load_dict(self.micro.bsdf()),
                mi.variant(),
            )
            self.__dict__["_scene_cache"] = scene
        mi = _mitsuba.mitsuba(scene[3])
        return mi, scene[1], scene[2]

    def __getstate__(self):
        state = dict(self.__dict__)
        state.pop("_scene_cache", None)
        return state

    def _launch(self, s: int, k: int, b: int):
        """Batch ``b`` of image ``(s, k)``: its spots, ray origins and directions (world), micro samples."""
        n = self._rays_in(b)
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(0, s, k, b)))
        spots = self._spots[s]
        spot = rng.integers(spots["count"], size=n)
        corner, centre, size = self._geometry(s, spot)
        xy = corner + rng.random((n, 2)) * size
        samples = rng.random((self.bounces, 3, n))
        slope = spots["slope"][spot]
        z = spots["height"][spot] - np.sum(slope * (xy - centre), axis=-1)
        aim = np.concatenate((xy, z[:, None]), axis=-1)
        light = np.einsum("nji,j->ni", _rotations(slope), self.incident[k])  # R^T i: the spot frame to world
        low, high = self._relief
        ny, nx = self.field.shape
        reach = math.hypot(nx + 2 * self.pad, (ny + 2 * self.pad) * self.field.spacing[1] / self.field.spacing[0])
        # start where the line of light crosses the level 1 px above the highest node: the light meets the surface
        # from above only (a ray entering the mesh's side below its edge would reach undersides)
        distance = np.minimum((high + 1.0 - z) / np.maximum(light[:, 2], 1e-12), reach + 2 * (high - low) + 4.0)
        distance = distance[:, None]
        return spot, aim + distance * light, -light, samples

    def run(self, task: Task, *, quads: bool = False) -> TaskResult:
        """Trace the batches of ``task`` (in this process) and return their partial sums (with ``quads=True`` also
        the pixel quad of every surface hit, for diagnostics)."""
        if not isinstance(task, Task):
            raise InvalidInputError(f"task must be a Task from Measurement.tasks(); got {type(task).__name__}.")
        if not isinstance(quads, bool):
            raise InvalidInputError(f"quads must be True or False; got {type(quads).__name__}.")
        mi, scene, bsdf = self._scene()
        faces = self._faces() if quads else None
        counts, hits, tallies, where = [], [], [], []
        for s, k, b in task.batches:
            spot, origins, directions, samples = self._launch(s, k, b)
            paths = _trace.trace(mi, scene, bsdf, origins, directions, samples, self.bounces)
            c, tally = self._deposit(s, k, spot, paths, directions[:, 2] >= 0)
            counts.append(c)
            hits.append(tally["hit"] + tally["from_below"])
            tallies.append(tally)
            if faces is not None:
                where.append(faces[paths.faces])
        found = None if faces is None else np.concatenate(where) if where else np.zeros((0, 2), np.int64)
        return TaskResult(task.batches, tuple(counts), tuple(hits), tuple(tallies), found)

    def _faces(self) -> np.ndarray:
        """The pixel quad of every face of the mesh, in Mitsuba's face order (:func:`._mesh.mesh_arrays`)."""
        found = _mesh.mesh_arrays(self.field, self.surface, self.pad)[2]
        assert found is not None  # quads=True
        return found

    def _deposit(
        self, s: int, k: int, spot: np.ndarray, paths: _trace.Paths, from_below: np.ndarray
    ) -> tuple[np.ndarray, dict]:
        i = self.incident[k]
        rotation = _rotations(self._spots[s]["slope"][spot[paths.ray]])
        o = np.einsum("nij,nj->ni", rotation, paths.direction)  # world to the spot frame
        o /= np.linalg.norm(o, axis=-1, keepdims=True)
        up = o[:, 2] > 0
        half = i + o[up]
        u = half[:, :2] / half[:, 2:3]
        c = i[2] * half[:, 2] / (half @ i)
        w = paths.weight[up] * c
        counts = self._bin(u, w)
        tally = {
            "rays": int(len(paths.hit)),
            "hit": int(paths.hit.sum()),
            "escaped": float(paths.weight.sum()),
            "detected": float(paths.weight[up].sum()),
            "weighted": float(w.sum()),  # detected light × c: the share on the nodes is Σ counts / this
            "bounce_limit": int(paths.limited.sum()),
            "underside": int(paths.underside.sum()),
            "from_below": int(np.count_nonzero(from_below & ~paths.hit)),
            "unmeasured": int(np.count_nonzero(~from_below & ~paths.hit)),
            "orders": np.bincount(paths.order, minlength=self.bounces + 1)[1:].tolist(),
        }
        return counts, tally

    def _bin(self, u: np.ndarray, w: np.ndarray) -> np.ndarray:
        """The detected weights ``w`` at half-slope offsets ``u`` (E, 2) binned onto the nodes (n, n), rows u_y."""
        n = self.pixels
        if self.binning == "bilinear":
            hist = SlopeHistogram(self.extent, n)
            hist.add(u[:, 0], u[:, 1], w)
            return hist.counts.reshape(n, n).copy()
        g = (u + self.extent) * ((n - 1) / (2 * self.extent))  # in pitches from the first node
        node = np.floor(g + 0.5)  # the cell [node − ½, node + ½) of pitches
        inside = np.all((node >= 0) & (node <= n - 1), axis=-1)
        k = node[inside].astype(np.int64)
        return np.bincount(k[:, 1] * n + k[:, 0], weights=w[inside], minlength=n * n).reshape(n, n)

    # -- the result ----------------------------------------------------------------------------
    def combine(self, results: Sequence[TaskResult]) -> MeasurementSet:
        """The measurement set from every task's result (any split, any order; each batch exactly once)."""
        found = {}
        for r in results:
            if not isinstance(r, TaskResult):
                raise InvalidInputError(f"results must be TaskResults of Measurement.run; got {type(r).__name__}.")
            for key, c, n, t in zip(r.batches, r.counts, r.hit, r.tallies):
                if key in found:
                    raise InvalidInputError(f"batch {key} (scale, incident, batch) is in two results.")
                found[key] = (c, n, t)
        missing = [(s, k, b) for s, k in self.images for b in range(self.batches) if (s, k, b) not in found]
        if missing:
            raise InvalidInputError(f"{len(missing)} batches have no result, the first {missing[0]}.")
        h = 2 * self.extent / (self.pixels - 1)
        images, records, inside = [], [], []
        for s, k in self.images:
            parts = [found[(s, k, b)] for b in range(self.batches)]
            counts = np.stack([p[0] for p in parts]) / h**2
            hits = np.array([p[1] for p in parts], dtype=np.float64)
            total = hits.sum()
            if total == 0:
                raise InvalidInputError(
                    f"no ray of the image at mu={self.scales[s]:g}, incident {self.incident[k].tolist()} met the "
                    "surface (light from below the spots' mean planes, or spots over holes)."
                )
            values = counts.sum(axis=0) / total
            spread = counts - values[None] * hits[:, None, None]
            var = self.batches / (self.batches - 1) * np.sum(spread**2, axis=0) / total**2
            sigma = np.maximum(np.sqrt(var), 1 / (total * h**2))
            mu, i = self.scales[s], self.incident[k]
            images.append(LobeImage(mu=mu, incident=i, extent=self.extent, values=values, sigma=sigma))
            tallies = [p[2] for p in parts]
            weighted = sum(t.get("weighted", 0.0) for t in tallies)
            share = float(sum(p[0].sum() for p in parts) / weighted) if weighted > 0 else 1.0
            records.append({**_image_record(mu, i, tallies, h), "light_inside": share})
            inside.append((share, mu))
        share, worst = min(inside)
        if share < synth.LIGHT_INSIDE:
            warnings.warn(
                f"the image at μ = {worst:g} holds only {100 * share:.0f} % of the light detected for it (extent "
                f"{self.extent:.4g}): the lobe is wider than the image (the facets' offsets from their spot's slope, "
                f"the {self.micro.kind} micro-facets' lobe and what interreflection adds); give a larger "
                f"extent (extent=, brdfscale synth --instrument raytraced --extent) for the images to hold at least "
                f"{100 * synth.LIGHT_INSIDE:.0f} % (each image's share is its record's light_inside).",
                LobeCutWarning,
                stacklevel=3,
            )
        return MeasurementSet(tuple(images), self._metadata(records, h))

    def measure(
        self,
        *,
        progress: bool = True,
        executor: str = EXECUTORS.default,
        address: str | None = None,
        workers: int | None = None,
        cpus_per_task: float = 1,
        retries: int = 2,
        batches_per_task: int | None = None,
    ) -> MeasurementSet:
        """Run every task — in this process, or as Ray tasks the way :func:`brdfscale.library.fit_library` runs a
        library's batches (:mod:`brdfscale._cluster`) — with a progress bar (one step per batch), and combine them:
        the same set, bit for bit, wherever the tasks ran (on one Mitsuba variant; the Ray workers build their scene
        in the variant this process resolved).

        Args:
            progress: show a progress bar (``BRDFSCALE_PROGRESS=0`` switches it off).
            executor: ``"process"`` (every task here), ``"ray"`` (a local Ray instance with ``workers`` CPUs, or the
                cluster at ``address``; the extra ``brdfscale[cluster]``), ``"auto"`` (default: Ray when ``address``
                or ``workers`` is given).
            address, workers, cpus_per_task, retries: as for :func:`brdfscale.library.fit_library` (a task's
                retries when its worker died).
            batches_per_task: batches per task (:meth:`tasks`; default one task per image).
        """
        from .. import _cluster

        workers, cpus_per_task, retries = _cluster.check_options(workers, cpus_per_task, retries)
        executor = _cluster.resolve_executor(executor, address, workers)
        tasks = self.tasks(batches_per_task)
        results: list[TaskResult | None] = [None] * len(tasks)
        with progress_bar(total=len(tasks) * self.batches, desc="instrument", unit="batch", enabled=progress) as bar:
            if executor == "process":
                for k, task in enumerate(tasks):
                    results[k] = self.run(task)
                    bar.update(len(task.batches))
            else:
                shipped = self._shipped()
                instead = "measure in this process, without address= and workers="
                with _cluster.ray_session(address, workers, instead=instead) as ray:
                    done = _cluster.as_completed(
                        ray, _run_task, shipped, tasks, cpus_per_task=cpus_per_task, retries=retries
                    )
                    try:
                        for k, result in done:
                            results[k] = result
                            bar.update(len(tasks[k].batches))
                    except Exception as err:  # noqa: BLE001 — a task failed (past its retries, if its worker died)
                        cause = getattr(err, "cause", None)
                        if isinstance(cause, BrdfscaleError):
                            raise cause from None
                        text = f"{type(err).__name__}: {' '.join(str(err).split())[:300]}"
                        raise BrdfscaleError(f"a task of the measurement failed on Ray: {text}") from err
        return self.combine([r for r in results if r is not None])

    def _shipped(self) -> Measurement:
        """A copy to send to other processes: its Mitsuba variant the one this process resolved (so every worker
        traces in the same variant), a token that lets a worker keep its scene from task to task
        (:func:`_run_task`), no scene of its own."""
        import copy
        import uuid

        mi = self._scene()[0]
        shipped = copy.copy(self)  # through __getstate__: without the scene
        shipped.variant = mi.variant()
        shipped.__dict__["_token"] = uuid.uuid4().hex
        return shipped

    def _metadata(self, records: list, h: float) -> dict:
        import brdfscale

        mi = self._scene()[0]
        field = self.field
        truth = {"facet_slope_mean": [], "facet_slope_covariance": []}
        for s in range(len(self.scales)):
            m = self._spots[s]["slope"]
            truth["facet_slope_mean"].append(m.mean(axis=0).tolist())
            truth["facet_slope_covariance"].append(np.cov(m.T).tolist() if len(m) > 1 else [[0.0, 0.0], [0.0, 0.0]])
        vertices, triangles = _mesh.mesh_counts(field, self.surface, self.pad)
        return {
            "generator": "brdfscale.instrument.measure",
            "surface": field.description,
            "spacing": field.spacing[0] if field.spacing[0] == field.spacing[1] else list(field.spacing),
            "shape": list(field.shape),
            "periodic": field.periodic,
            "unit": field.unit,
            "unmeasured": 0 if field.mask is None else int(np.count_nonzero(~field.mask)),
            "micro": self.micro.record(),
            "scales": self.scales,
            "pixels": int(self.pixels),
            "extent": float(self.extent),
            "noise": None,
            "resolution": 0.0,
            "albedo": self.micro.amplitude,
            "seed": self.seed,
            "truth": truth,
            "instrument": {
                "type": "raytraced",
                "brdfscale": brdfscale.__version__,
                "mitsuba": mi.__version__,
                "variant": mi.variant(),
                "rays": self.rays,
                "batches": self.batches,
                "bounces": self.bounces,
                "spots": [self._spots[s]["count"] for s in range(len(self.scales))],
                "windows": [self._spots[s]["windows"] for s in range(len(self.scales))],
                "alignment": "each spot rotated onto its mean plane (the window's facet slope), minimal rotation",
                "micro": self.micro.record(),
                "seed": self.seed,
                "margin_px": self.pad,
                "surface": self.surface,
                "mesh": {"vertices_max": vertices, "triangles_max": triangles},
                "detector": {
                    "domain": "half_slope",
                    "node_pitch": h,
                    "binning": self.binning,
                    "cell": (
                        "each path counts in the node whose pitch × pitch cell of half-slope offsets holds it"
                        if self.binning == "nearest"
                        else "each path shared among the four nodes around it (bilinear, cloud in cell)"
                    ),
                    "solid_angle": "4 (i·h) cos³θ_h · pitch² per node (spot frame)",
                },
                "sigma": f"standard error of the ratio estimate over {self.batches} batches, floored at 1/(N·pitch²)",
                "images": records,
            },
        }


_WORKER_PLAN: dict[str, Measurement] = {}
"""On a Ray worker: the plan of the measurement it traces (by its token), kept from task to task so that its scene
is built once per worker and measurement; replaced by the next measurement's."""


def _run_task(plan: Measurement, task: Task) -> TaskResult:
    """One task on a Ray worker (:meth:`Measurement.measure`): ``plan.run(task)`` with the worker's copy of the plan."""
    token = plan.__dict__.get("_token", "")
    kept = _WORKER_PLAN.get(token)
    if kept is None:
        _WORKER_PLAN.clear()
        _WORKER_PLAN[token] = kept = plan
    return kept.run(task)


def _image_record(mu: float, i: np.ndarray, tallies: list[dict], h: float) -> dict:
    keys = ("rays", "hit", "escaped", "detected", "bounce_limit", "underside", "from_below", "unmeasured")
    total = {key: sum(t[key] for t in tallies) for key in keys}
    lit = max(total["hit"] + total["from_below"], 1)
    orders = np.sum([t["orders"] for t in tallies], axis=0)
    return {
        "mu": mu,
        "incident": i.tolist(),
        "rays": total["rays"],
        "hit": total["hit"],
        "from_below": total["from_below"],
        "unmeasured": total["unmeasured"],
        "escaped_fraction": total["escaped"] / lit,
        "detected_fraction": total["detected"] / lit,
        "bounce_limit": total["bounce_limit"],
        "underside": total["underside"],
        "escaped_by_order": orders.tolist(),
        "detector_solid_angle_at_specular": 4 * float(i[2]) * h**2,
    }


def _rotations(m: np.ndarray) -> np.ndarray:
    """The smallest rotations taking the normals ``(m, 1)/|(m, 1)|`` to z, shape (S, 3, 3) (Rodrigues)."""
    n = np.concatenate((m, np.ones((len(m), 1))), axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    a = np.stack((n[:, 1], -n[:, 0], np.zeros(len(n))), axis=-1)  # n × z
    K = np.zeros((len(n), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -a[:, 2], a[:, 1]
    K[:, 1, 0], K[:, 1, 2] = a[:, 2], -a[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -a[:, 1], a[:, 0]
    c = n[:, 2][:, None, None]
    return np.eye(3)[None] + K + K @ K / (1 + c)


def measure(
    field: HeightField,
    scales,
    incident: Float[ArrayLike, "*k 3"] | Sequence[float] | Sequence[Sequence[float]],
    *,
    extent: float,
    pixels: int = 65,
    micro: lobes.AbstractLobe | stats.AbstractSlopeDensity | None = None,
    rays: int = DEFAULT_RAYS,
    bounces: int = 1,
    spots: int | None = None,
    batches: int = DEFAULT_BATCHES,
    fresnel: complex | float | None = None,
    surface: str = MESHES.default,
    pad: int | None = None,
    binning: str = BINNINGS.default,
    seed: int = 0,
    variant: str | None = None,
    progress: bool = True,
    executor: str = EXECUTORS.default,
    address: str | None = None,
    workers: int | None = None,
) -> MeasurementSet:
    """Measure the lobes of ``field`` at each scale μ and incident direction with the ray-traced instrument.

    The instrument, its conventions (spot alignment, the image as ``4 cosθ_o cos⁴θ_h ρ``, the detector's solid angle,
    σ) and its determinism: the module docstring and docs/instrument.md.

    Args:
        field: the surface (:class:`brdfscale.synth.HeightField`, synthesised or measured; unmeasured pixels are
            left out of the mesh).
        scales: spot sizes μ, whole numbers of pixels (length units), as for synth.gonioreflectometer.
        incident: unit direction(s) towards the light in the aligned spot's frame, (3,) or (k, 3), z > 0.
        extent: half-width ``a`` of the image grid (slope units).
        pixels: nodes per image axis (≥ 2).
        micro: the facets' micro-BRDF (``lobes.Mirror/Beckmann/GGX`` or the stats density a field carries);
            default the field's ``micro``.
        rays: rays per image (≥ ``batches``).
        bounces: the most reflections a path may take, 1–64 (1: single scattering, masked light lost).
        spots: spots per scale, drawn without replacement from the whole windows by the seed; None: every window.
        batches: independent batches per image σ is estimated from (≥ 2).
        fresnel: None (F = 1) or the facets' refractive index ``n + ik``.
        surface: ``"pixel_facets"`` (the HeightField's pixel facets, the surface synth takes statistics of) or
            ``"triangles"`` (the continuous piecewise-linear surface): :mod:`._mesh`.
        pad: the periodic margin in pixels of a periodic field's mesh (default :func:`._mesh.default_pad`; 0 for a
            measured field).
        binning: ``"nearest"`` (each path in the node whose ``h × h`` cell holds it: independent node errors) or
            ``"bilinear"`` (cloud-in-cell shares, as synth.gonioreflectometer bins facets):
            :data:`brdfscale.choices.BINNINGS`.
        seed: an integer ≥ 0; the same seed gives the same measurement bit for bit (on one variant).
        variant: Mitsuba's variant (None: the first of cuda_ad_rgb, llvm_ad_rgb, scalar_rgb that runs here).
        progress: show a progress bar (one step per batch; ``BRDFSCALE_PROGRESS=0`` switches it off).
        executor: where the tasks (one per image) run: ``"process"`` (here), ``"ray"`` (Ray tasks, the extra
            ``brdfscale[cluster]``: a local instance of ``workers`` CPUs or the cluster at ``address``) or
            ``"auto"`` (default: Ray when ``address`` or ``workers`` is given) — the same result, bit for bit
            (:meth:`Measurement.measure`, which also takes ``cpus_per_task``, ``retries`` and
            ``batches_per_task``).
        address: a Ray cluster's address (``"auto"``, ``"HOST:6379"``).
        workers: CPUs of a local Ray instance started (and stopped) for the measurement.

    Returns:
        A :class:`brdfscale.MeasurementSet`, one image per (μ, i), scales outermost, with σ the Monte Carlo standard
        error; ``metadata`` in synth.gonioreflectometer's keys plus ``instrument`` (variant, versions, rays, batches,
        bounces, spots, micro, seed, margin, mesh size, detector, and per image the fractions of light that met the
        surface, escaped, was detected, or was lost at the bounce limit or through a hole, and ``light_inside``: the
        share of the detected light that fell on the image's nodes).

    Warns:
        LobeCutWarning: an image holds less than :data:`brdfscale.synth.LIGHT_INSIDE` of its detected light (the
            extent is too small); the message names the worst scale and its share (``tests/test_instrument.py``).

    Raises:
        InvalidInputError: any argument out of its range (named, with what is accepted), a spot size that is not a
            whole number of pixels, a mesh above ``MAX_MESH_BYTES`` — before any ray is traced.
        MissingDependencyError: Mitsuba is not installed or the variant asked for cannot run here, or Ray is not
            installed with ``executor="ray"`` (one line saying what to install).
        BrdfscaleError: a Ray task failed for another reason than bad input (its worker died past its retries).
    """
    plan = Measurement(
        field,
        scales,
        incident,
        extent=extent,
        pixels=pixels,
        micro=micro,
        rays=rays,
        bounces=bounces,
        spots=spots,
        batches=batches,
        fresnel=fresnel,
        surface=surface,
        pad=pad,
        binning=binning,
        seed=seed,
        variant=variant,
    )
    return plan.measure(progress=progress, executor=executor, address=address, workers=workers)
