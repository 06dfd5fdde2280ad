"""ΔΣ(μ0, μ_k) from the images' own second moments: what the data determine without a model (issue 31 item 2).

A lobe image at scale μ holds ``v_j ≈ A g_μ(u_j)`` at its nodes ``u_j`` with noise σ_j. Its second central moment
over the offsets,

    M0 = Σ_j v_j,   m = Σ_j v_j u_j / M0,   C = Σ_j v_j (u_j − m)(u_j − m)ᵀ / M0,

estimates the covariance of the lobe without assuming its shape, and by seed Eq. 4.4 with cumulants adding
(``G(W, μ_k) = G(W, μ0) S(W, μ0)/S(W, μ_k)``) the lobe at μ_k is the lobe at μ0 widened by ΔΣ(μ0, μ_k):

    ΔΣ_k = C(μ_k) − C(μ0)

whatever the lobe's and the increments' shapes — Gaussian, heavy-tailed, kurtotic — as long as the images hold the
lobes. What a detector adds to every image alike cancels in the difference: the cell of a node (``h²/12`` per axis
for cell averages, ``h²/6`` for the cloud-in-cell shares of ``brdfscale.synth``), an angular resolution blur, the
micro-facets' own lobe — when every image has the same node pitch (``extent`` and pixels) and every lobe spreads
over several cells (its light then falls anywhere within them); a set whose pitches differ between scales, or a
lobe narrower than ``ADEQUACY.min_lobe_pixels`` (1) pitch (rms along its narrower axis, by more than 3 standard errors
of its variance; mirror facets at μ0 of one pixel: every offset is 0, a point on a node that adds no cell term),
gets a ``note`` saying the cell terms do not
cancel.

**Standard errors.** C is a ratio of sums linear in the values; to first order ``∂C_ab/∂v_j = ((u_j − m)_a (u_j −
m)_b − C_ab)/M0`` (the mean's own derivative drops out: ``Σ v_j (u_j − m) = 0``), so with independent pixel noise
``Var C_ab = Σ_j (∂C_ab/∂v_j)² σ_j²``. A scale with several images (incidences) averages their C with equal
weights. ΔΣ_k's error adds the two scales' in quadrature (different images, independent noise). Masked pixels (σ
unknown, weight 0) are left out of every sum.

**Truncation.** Light beyond the image is not in the sums, and the second moment lives in the tails: an image whose
lobe has heavy tails and holds 99.9 % of its light may hold 80 % of its variance (the real files of tests/data:
docs/fitting.md). The outermost ring of an image's valid pixels tells: when its summed light is above
``ADEQUACY.significance`` (3) times its noise, the lobe goes on past the edge, the moments miss its tails, and
each entry that uses the image is marked ``"truncated": true`` with a note — the value is then not ΔΣ but the
widening of the part of the lobe the image holds. An entry whose images' edges are within their noise is
``"truncated": false``.

Verified in tests/test_moments.py: the moments and their errors by hand on small images, the errors against the
scatter over noise realisations, ΔΣ of noise-free synthesised images against the recorded truth
(:func:`fitting.covariance_truth`), the edge check on a cut lobe.

**A model's images.** ``values=`` takes the moments of other values on the same nodes with the same σ — a fitted
model's prediction (``model.predict(theta, data)``): the same estimator on the same pixels, so truncation, the
cells and the micro lobe act on both alike, and the difference of the two is a test of the model that needs no rule
for the tails an image cannot show (:func:`fitting.assess`, point 2).
"""

import numpy as np
from jaxtyping import ArrayLike, Float

from brdfscale import InvalidInputError
from brdfscale.choices import ADEQUACY

from ._data import Dataset
from ._model import require_dataset


__all__ = ["moment_covariance_differences"]

TRUNCATED_NOTE = (
    "an image's outermost ring holds light above its noise: the lobe goes on past the image's edge and the second "
    "moments miss its tails (the value is the widening of what the images hold) — measure with a larger extent"
)
"""The ``note`` of an entry whose images do not hold their lobes."""

PITCH_NOTE = "the images' node pitches differ between the two scales: their cell terms (h²/12 per axis) do not cancel"
"""The ``note`` of an entry whose two scales' images have different node pitches."""

NARROW_NOTE = (
    "a lobe narrower than a node pitch: the detector's cell term (up to h²/12 per axis for cell averages, h²/6 for "
    "cloud-in-cell shares) is not the same at both scales — ΔΣ may be off by that much"
)
"""The ``note`` of an entry with a lobe narrower than ``ADEQUACY.min_lobe_pixels`` node pitches (rms, narrower axis,
even 3 standard errors of its variance above the estimate)."""


def weighted_moments(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mean m (2,), the centred offsets u − m (N, 2) and the covariance Σ v (u − m)(u − m)ᵀ / Σ v (2, 2) of
    offsets ``u`` (N, 2) weighted by values ``v`` (N,) of positive sum: the one computation of a lobe's moments
    over a selection of its pixels (here every valid pixel; :func:`fitting._adequacy.lobe_moments` the
    significant ones)."""
    total = v.sum()
    mean = v @ u / total
    d = u - mean
    return mean, d, (d * v[:, None]).T @ d / total


def _image_moments(data: Dataset, values: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """Image ``i``'s covariance C (2, 2) of ``values`` (the data's, or a model's on its nodes), its standard errors
    (2, 2) by the data's σ, and whether its edge holds light above noise."""
    n = data.image_sizes[i]
    v = np.asarray(values[i, : n * n], dtype=float)
    w = np.asarray(data.weight[i, : n * n], dtype=float)
    u = np.asarray(data.offsets[i, : n * n], dtype=float)
    valid = w > 0
    sigma = np.divide(1.0, w, out=np.zeros_like(w), where=valid)
    v = np.where(valid, v, 0.0)
    total = v.sum()
    if not total > 0:
        nan = np.full((2, 2), np.nan)
        return nan, nan, False
    _, d, cov = weighted_moments(u, v)
    products = d[:, :, None] * d[:, None, :]  # (N, 2, 2)
    grad = (products - cov[None]) / total
    std = np.sqrt(np.einsum("jab,j->ab", grad**2, sigma**2))
    ring = np.zeros((n, n), bool)
    ring[[0, -1], :] = ring[:, [0, -1]] = True
    ring = ring.ravel() & valid
    edge_noise = np.sqrt(np.sum(sigma[ring] ** 2))
    truncated = bool(edge_noise > 0 and v[ring].sum() > ADEQUACY.significance * edge_noise)
    return cov, std, truncated


def moment_covariance_differences(data: Dataset, values: Float[ArrayLike, "images pixels"] | None = None) -> list[dict]:
    """ΔΣ(μ0, μ_k) = C(μ_k) − C(μ0) of the images' own second moments for every coarser scale, with standard errors
    (module docstring): ``{"mu0", "mu", "value": [[xx, xy], [xy, yy]], "std": [[…], […]], "truncated": bool}``
    (slope units², the entries of :func:`fitting.FitResult.covariance_differences`; ``"note"`` when truncated or
    when the two scales' node pitches differ). Model-independent: no fit is needed, and any model's ΔΣ can be
    compared with it. A scale whose images hold no positive light has None values.

    ``values``: the values whose moments are taken, in ``data.values``' layout (default: the data's own) — a model's
    prediction on the same nodes, whose ΔΣ over the images' pixels is then comparable with the data's (module
    docstring, "A model's images"); the standard errors and the edge check stay the data's σ.

    Raises:
        InvalidInputError: ``data`` is not a :class:`fitting.Dataset`, or ``values`` is not of ``data.values``' shape.
    """
    require_dataset(data, "moment_covariance_differences(data)")
    if values is None:
        values = np.asarray(data.values)
    else:
        values = np.asarray(values, dtype=float)
        if values.shape != tuple(data.values.shape):
            raise InvalidInputError(
                f"moment_covariance_differences(data, values): values must have data.values' shape "
                f"{tuple(data.values.shape)} (images × padded pixels, as model.predict(theta, data) gives); "
                f"got {values.shape}."
            )
    scales = np.asarray(data.scales)
    per_scale = []
    for k in range(len(scales)):
        images = list(data.images_of_scale(k))
        moments = [_image_moments(data, values, i) for i in images]
        cov = np.mean([m[0] for m in moments], axis=0)
        std = np.sqrt(np.sum([m[1] ** 2 for m in moments], axis=0)) / len(moments)
        pitch = [2 * data.extents[i] / (data.image_sizes[i] - 1) for i in images]
        # narrow: even 3 standard errors above its estimate, the narrower axis's variance is below (min_lobe_pixels
        # pitches)² — a noisy image's C is not called narrow for its noise
        narrow = any(
            float(np.linalg.eigvalsh(m[0])[0]) + 3 * float(np.max(m[1])) < (ADEQUACY.min_lobe_pixels * h) ** 2
            for m, h in zip(moments, pitch)
        )
        per_scale.append((cov, std, any(m[2] for m in moments), {round(h, 12) for h in pitch}, narrow))
    c0, s0, t0, p0, n0 = per_scale[0]
    out = []
    for k in range(1, len(scales)):
        ck, sk, tk, pk, nk = per_scale[k]
        value, std = ck - c0, np.sqrt(sk**2 + s0**2)
        finite = np.isfinite(value)
        notes = [TRUNCATED_NOTE] if t0 or tk else []
        notes += [PITCH_NOTE] if p0 != pk or len(p0 | pk) > 1 else []
        notes += [NARROW_NOTE] if n0 or nk else []
        out.append(
            {
                "mu0": float(scales[0]),
                "mu": float(scales[k]),
                "value": [[float(value[a, b]) if finite[a, b] else None for b in range(2)] for a in range(2)],
                "std": [[float(std[a, b]) if finite[a, b] else None for b in range(2)] for a in range(2)],
                "truncated": bool(t0 or tk),
                **({"note": "; ".join(notes)} if notes else {}),
            }
        )
    return out
