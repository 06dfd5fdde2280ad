"""One batch of light paths through the meshed surface in Mitsuba 3: first hit, micro-BRDF samples, visibility.

A path starts far above the surface on the line through its aim point along the incident direction (the light),
and is followed through up to ``bounces`` reflections. At each hit the facet's micro-BRDF is sampled (Mitsuba's
``BSDF.sample``, whose weight is ``f·cosθ_o/pdf``); the reflected ray is intersected with the scene (masking, and the
next reflection) or, after the last allowed reflection, tested for visibility (``Scene.ray_test``): a path that
leaves the surface unobstructed escapes with its direction and throughput, one that hits the surface again after
its last allowed reflection is lost (recorded). A hit on a triangle's underside ends the path: as light that never
met the measured surface when it is the first hit (light through an unmeasured hole, or from below the surface), as
lost light after a reflection. Shadowing needs no extra ray: the light reaches only the first surface on its line.

The batch runs as a few vectorised Mitsuba calls in a JIT variant (``llvm_*``, ``cuda_*``) and ray by ray in a
scalar variant (much slower; for machines without LLVM ≥ 19).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class Paths:
    """What a batch's paths did: ``hit`` (N,) bool — the light met the surface from above; per escaped path its
    index ``ray``, world direction ``direction`` (E, 3) and throughput ``weight`` (E,) and the reflections it took
    ``order`` (E,); ``limited`` (N,) bool — lost at the bounce limit; ``below`` (N,) bool — the light's first hit
    was an underside; ``underside`` (N,) bool — lost on an underside after a reflection;
    ``faces`` — the triangles hit (every hit of every path; for tests)."""

    hit: np.ndarray
    ray: np.ndarray
    direction: np.ndarray
    weight: np.ndarray
    order: np.ndarray
    limited: np.ndarray
    below: np.ndarray
    underside: np.ndarray
    faces: np.ndarray


def _vector(mi, cls, a: np.ndarray):
    return cls(*(mi.Float(np.ascontiguousarray(a[:, c], dtype=np.float32)) for c in range(a.shape[1])))


def trace(mi, scene, bsdf, origins: np.ndarray, directions: np.ndarray, samples: np.ndarray, bounces: int) -> Paths:
    """Follow ``len(origins)`` paths (``samples``: (bounces, 3, N) uniform numbers for the micro-BRDF)."""
    if mi.variant().startswith("scalar"):
        return _trace_scalar(mi, scene, bsdf, origins, directions, samples, bounces)
    import drjit as dr

    n = len(origins)
    ray = mi.Ray3f(_vector(mi, mi.Point3f, origins), _vector(mi, mi.Vector3f, directions))
    si = scene.ray_intersect(ray)
    front = si.is_valid() & (dr.dot(ray.d, si.n) < 0)
    below = np.array(si.is_valid() & ~front)
    underside = np.zeros(n, bool)
    hit = np.array(front)
    faces = [np.array(si.prim_index)[np.array(si.is_valid())]]
    active = mi.Bool(front)
    throughput = mi.Float(1.0)
    ctx = mi.BSDFContext()
    index = np.arange(n)
    rays, dirs, weights, orders = [], [], [], []
    limited = np.zeros(n, bool)
    for b in range(bounces):
        s1 = mi.Float(np.ascontiguousarray(samples[b, 0], dtype=np.float32))
        s2 = mi.Point2f(
            mi.Float(np.ascontiguousarray(samples[b, 1], dtype=np.float32)),
            mi.Float(np.ascontiguousarray(samples[b, 2], dtype=np.float32)),
        )
        bs, weight = bsdf.sample(ctx, si, s1, s2, active)
        throughput = throughput * weight[0]
        active = active & (weight[0] > 0)
        out = si.to_world(bs.wo)
        ray = si.spawn_ray(out)
        if b < bounces - 1:
            si = scene.ray_intersect(ray, active)
            valid = si.is_valid()
            escaped = active & ~valid
            front = valid & (dr.dot(ray.d, si.n) < 0)
            underside |= np.array(active & valid & ~front)
            faces.append(np.array(si.prim_index)[np.array(active & valid)])
            active = active & front
        else:
            blocked = scene.ray_test(ray, active)
            escaped = active & ~blocked
            limited = np.array(active & blocked)
        dr.eval(escaped, out, throughput, active)
        e = np.array(escaped)
        if e.any():
            rays.append(index[e])
            dirs.append(np.stack([np.array(out.x)[e], np.array(out.y)[e], np.array(out.z)[e]], axis=-1))
            weights.append(np.array(throughput)[e])
            orders.append(np.full(int(e.sum()), b + 1))
        if not np.array(active).any():
            break
    return _paths(hit, rays, dirs, weights, orders, limited, below, underside, faces)


def _paths(hit, rays, dirs, weights, orders, limited, below, underside, faces) -> Paths:
    return Paths(
        hit=hit,
        ray=np.concatenate(rays) if rays else np.zeros(0, np.int64),
        direction=np.concatenate(dirs).astype(np.float64) if dirs else np.zeros((0, 3)),
        weight=np.concatenate(weights).astype(np.float64) if weights else np.zeros(0),
        order=np.concatenate(orders) if orders else np.zeros(0, np.int64),
        limited=limited,
        below=below,
        underside=underside,
        faces=np.concatenate(faces).astype(np.int64) if faces else np.zeros(0, np.int64),
    )


def _trace_scalar(mi, scene, bsdf, origins, directions, samples, bounces) -> Paths:
    """:func:`trace` ray by ray (a scalar variant)."""
    import drjit as dr

    n = len(origins)
    hit, limited, below, underside = (np.zeros(n, bool) for _ in range(4))
    rays, dirs, weights, orders, faces = [], [], [], [], []
    ctx = mi.BSDFContext()
    for r in range(n):
        ray = mi.Ray3f(mi.Point3f(*map(float, origins[r])), mi.Vector3f(*map(float, directions[r])))
        si = scene.ray_intersect(ray)
        if not si.is_valid():
            continue
        faces.append(int(si.prim_index))
        if not dr.dot(ray.d, si.n) < 0:
            below[r] = True
            continue
        hit[r] = True
        throughput = 1.0
        for b in range(bounces):
            bs, weight = bsdf.sample(ctx, si, float(samples[b, 0, r]), mi.Point2f(*map(float, samples[b, 1:, r])))
            throughput *= float(weight[0])
            if not throughput > 0:
                break
            out = si.to_world(bs.wo)
            ray = si.spawn_ray(out)
            if b < bounces - 1:
                si = scene.ray_intersect(ray)
                if si.is_valid():
                    faces.append(int(si.prim_index))
                    if not dr.dot(ray.d, si.n) < 0:
                        underside[r] = True
                        break
                    continue
            elif scene.ray_test(ray):
                limited[r] = True
                break
            rays.append(np.array([r]))
            dirs.append(np.array([[float(out.x), float(out.y), float(out.z)]]))
            weights.append(np.array([throughput]))
            orders.append(np.array([b + 1]))
            break
    return _paths(hit, rays, dirs, weights, orders, limited, below, underside, [np.array(faces, np.int64)])
