"""Can a fit's outcome be trusted? The one place that decides: :func:`assess` and :class:`Outcome`.

Four questions, in this order (the first that fails decides the status; every problem found
is listed in :attr:`Outcome.problems`):

1. **Resolved** (:func:`lobe_widths`, :func:`resolution`): can the data determine how the lobe
   changes with scale at all? A lobe's width is measured from the data's own second moments:
   the pixels above ``significance`` σ and above ``peak_fraction`` of the image's peak (noise
   far from the lobe would otherwise dominate the moments; the cut truncates a Gaussian lobe at
   2.45 standard deviations, which underestimates its rms width by about 8 %) give a 2 × 2
   covariance C of the offsets u; the lobe's width is ``√λ_min(C)`` (its narrower principal
   axis) in image pixel pitches ``h = 2·extent/(n − 1)``. Below ``min_lobe_pixels`` (1: a
   Gaussian lobe of rms width one pitch has ``e^(−π²/2)`` = 0.7 % of its spectrum's peak at the
   Nyquist frequency, so it is sampled without loss; a narrower one aliases, and a lobe within a
   pixel or two says nothing) at any scale, the lobe's change with scale is unmeasurable — a fit
   of such data reports ratios of 1 ± 1e-14 that say nothing about the surface. Status ``"undetermined"``.
   A scale with an image of fewer than two significant pixels whose peak is below
   ``significance/peak_fraction`` σ (60 σ) is *faint*: there the noise, not the lobe's shape,
   hides its neighbours (any pixel at 5 % of a ≥ 60 σ peak would be above 3 σ), so the first
   remedy is more counts — a longer exposure —; the reason adds the smaller extent as the second,
   since a faint lobe may also lie within a pixel. A single pixel above 60 σ is a *narrow* lobe
   (width 0), as is a resolved lobe under ``min_lobe_pixels`` wide: the reason asks for a
   smaller extent or more pixels.

2. **Adequate** (:func:`assess`): is the model consistent with the data? With the whitened
   residuals ``r = (prediction − data)/σ`` at the estimate (masked pixels left out):

   * χ²/dof per scale: ``χ²_k = Σ r²`` over the images of scale k, ``dof_k = n_k − p·n_k/N``
     (the model's p parameters shared in proportion to the scale's share of the N valid
     pixels); the scale fails when ``χ²_k/dof_k > max_reduced_chi2`` (1.5) and its χ² tail
     probability ``P(χ²_{dof_k} ≥ χ²_k) < p_value`` (1e-3);
   * residual structure: the lag-1 autocorrelation of the residuals along the rows and along
     the columns of every image, ``ρ = Σ r_j r_{j+1} / √(Σ r_j² Σ r_{j+1}²)`` over neighbouring valid
     pairs (:func:`lag1_correlation`).
     For a correct model with independent noise, ``ρ·√n_pairs`` is standard normal; a misfit
     that is smooth over the image (a wrong lobe shape, an anisotropic lobe fitted by an
     isotropic model, a cross-shaped residual) makes neighbours agree and ρ large. The test
     fails when ``ρ > max_lag1`` (0.1) and its one-sided p-value, Bonferroni-corrected over the
     fit's 2 × images tests, is below ``p_value``. False-alarm rate and power are measured in
     tests/test_adequacy.py (model-generated data over seeds; GGX data fitted by a Beckmann model).
   * second moments: ΔΣ(μ0, μ) of the model's images against the images' own, both by
     :func:`fitting.moment_covariance_differences` on the same pixels with the data's σ (the model's prediction at
     the estimate in place of the data's values): the statistic the fit reports, measured without a model. The same
     estimator on the same pixels cuts both alike where the lobe passes the image's edge, so the test needs no
     rule for tails an image does not show. ``z = (ΔΣ_model − ΔΣ_data)/std`` per entry (xx, xy, yy); the scale
     fails when the largest |z|'s two-sided p-value, Bonferroni-corrected over the 3 entries of every coarser
     scale, is below ``p_value`` — a significance test alone: ΔΣ is what the fit is for, so a miss the data
     resolve is a miss. It catches what χ² and the neighbours' correlation miss: faint, broad tails, each pixel
     within its noise, that carry the second moment (tests/test_adequacy.py: a Gaussian core with such tails
     passes both and fails this; the lobes of the real files of tests/data).

   * where the misfit lies (a diagnosis, no test: :func:`away_from_lobe`): the share of a scale's χ² excess
     ``Σ (r² − 1)`` at pixels where the model predicts less than ``away_fraction`` (1 %) of its peak, and the
     slope offset of the largest excess of data over model there. Where the scale that fails worst (whichever
     test it fails) has more than ``away_verdict_share`` (½) of its excess away from the lobe, the verdict says so,
     with that offset: the model holds the lobe and misses light beyond it
     (tails, or satellite peaks — the lobes synthesised from tests/data's mnt-1, whose pixel slopes have side
     peaks at ±0.16 from rare steps of one height, show them at that offset; docs/fitting.md).

   A scale where the prediction at the estimate is not finite at a valid pixel (an overflow or
   0/0 of the model; masked pixels are left out whatever it predicts there) has no χ² and no
   autocorrelation: its figures are None (null in fit.json; ``brdfscale fit`` prints
   "undefined"), never NaN — a NaN compares False with every threshold and would pass — and it
   is inadequate first of all, the reason naming the scale and how many pixels.

   * against a known truth (only where the caller gives one: ``covariance_truth``, the ΔΣ(μ0, μ_k) of the surface a
     synthesised set was made from, :func:`fitting.covariance_truth` of its metadata; ``brdfscale fit`` and
     :func:`fitting.write_report` pass it): the fit's ΔΣ entries' pulls ``(estimate − truth)/std``
     (:func:`fitting.compare_covariance_differences`); the fit fails when the largest |pull|'s two-sided p-value,
     Bonferroni-corrected over the entries with a standard error, is below ``p_value``. It catches what no test
     of the images can: at low counts a lobe's tails lie below the noise, so a Gaussian lobe fits every scale
     (χ², neighbours and the images' own moments, whose errors are then large, all pass) while its ΔΣ — its
     core's widening — misses the surface's second moments by many of its own standard errors (the lobes
     synthesised from the real files of tests/data at ``poisson:0.05:1``: docs/benchmarks.md). Without the
     check such a fit ended "ok". Its line comes after those of the images' own tests, whatever its size (they say
     where the model misses the images; it leads only where they pass).

   Status ``"inadequate"``, naming the worst scale and its figure.
3. **Converged**: the optimiser's best start reported success (:attr:`FitResult.status`) and,
   when sampled, the chains passed R̂ and ESS (:attr:`SampleResult.status`, which names the
   failed criterion). Status ``"not_converged"``.

4. **Identified** (:func:`undetermined_statistics`; asked last: the standard errors mean something
   only at a converged optimum of an adequate model): every statistic the fit reports as what the
   data determine — each ΔΣ(μ0, μ_k) component (``FitResult.covariance_differences``) and each
   ratio ``S(W, μ0)/S(W, μ_k)`` (``FitResult.ratios``) — has a standard error. One whose std is
   None (the Laplace analysis, :meth:`brdfscale.laplace.Laplace.quantity_is_determined`: the
   undetermined directions move it more than the determined ones, or it is not finite) makes the
   outcome ``"undetermined"``, and the reason names them: a fit never ends "ok" with a reported
   statistic the data cannot determine. Left out: an entry the model fixes by construction
   (``ΔΣ_xy`` of an isotropic model, ``"fixed"``: fitting._derived) and a ΔΣ that is not defined
   for the statistics (value None: GGX slopes have no second moment).

The thresholds are :data:`brdfscale.choices.ADEQUACY` (:class:`brdfscale.choices.AdequacyDefaults`).
``brdfscale fit`` maps the status to its exit status (0, 5, 6, 7; brdfscale._cli).
"""

import dataclasses
import math
from typing import Literal

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Bool, Float

from brdfscale import InvalidInputError
from brdfscale.checks import real
from brdfscale.choices import ADEQUACY, AdequacyDefaults

from ._data import Dataset
from ._derived import compare_covariance_differences, DIFFERENCE_ENTRIES
from ._model import predict_images
from ._moments import moment_covariance_differences, weighted_moments
from ._problem import check_fit, Problem
from ._result import FitResult


__all__ = ["Outcome", "assess", "away_from_lobe", "lag1_correlation", "lobe_moments", "lobe_widths", "resolution"]

Status = Literal["ok", "undetermined", "inadequate", "not_converged"]


@dataclasses.dataclass(frozen=True)
class Outcome:
    """What :func:`assess` (or :func:`resolution`) decided.

    ``status``: ``"ok"``, ``"undetermined"``, ``"inadequate"`` or ``"not_converged"`` (the first
    failed check, module docstring); ``reason``: one line saying why and what to do ("" when
    ok); ``problems``: every failed check's line; ``scales``: one dict per measured scale
    (``mu``, ``width_px`` — the lobe's narrower principal rms width in image pixels —, and after
    a fit ``chi2``, ``dof``, ``reduced_chi2``, ``chi2_p``, ``lag1_rows``, ``lag1_cols``,
    ``lag1_p``, the largest autocorrelations over the scale's images and the Bonferroni-corrected
    p-value of the larger, ``moments_z``, ``moments_entry``, ``moments_p``, the second-moment test of the pair
    (μ0, μ), ``away_share``, ``away_peak_offset``, ``away_peak_z``, where the misfit lies (:func:`away_from_lobe`)
    — None, not NaN, where the prediction is not finite at a valid pixel, and the moments' at μ0:
    module docstring, point 2); ``thresholds``: those used.
    """

    status: Status
    reason: str
    problems: tuple[str, ...]
    scales: tuple[dict, ...]
    thresholds: AdequacyDefaults = ADEQUACY

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_json(self) -> dict:
        return {
            "status": self.status,
            "reason": self.reason,
            "problems": list(self.problems),
            "scales": [dict(s) for s in self.scales],
            "thresholds": dataclasses.asdict(self.thresholds),
        }


def _mu_text(mu: float, unit: str | None) -> str:
    return f"μ = {mu:.4g} {unit or 'px'}"


def lobe_moments(
    data: Dataset, i: int, thresholds: AdequacyDefaults = ADEQUACY
) -> tuple[np.ndarray, np.ndarray] | None:
    """The centre (2,) and covariance (2, 2) of image ``i``'s lobe over the offsets u, from its
    significant pixels (above ``significance`` σ and ``peak_fraction`` of the peak; module
    docstring, point 1); None when fewer than two pixels are significant."""
    n = data.image_sizes[i]
    v, w = np.asarray(data.values[i, : n * n]), np.asarray(data.weight[i, : n * n])
    u = np.asarray(data.offsets[i, : n * n])
    valid = w > 0
    peak = float(np.max(np.where(valid, v, -np.inf)))
    keep = valid & (v * w > thresholds.significance) & (v > thresholds.peak_fraction * peak)
    if np.count_nonzero(keep) < 2:
        return None
    centre, _, cov = weighted_moments(u[keep], v[keep])
    return centre, cov


def _widths_and_faint(data: Dataset, thresholds: AdequacyDefaults) -> tuple[list[float], list[bool]]:
    """Per scale: :func:`lobe_widths`' width, and whether an image of the scale is faint (fewer
    than two significant pixels, :func:`lobe_moments` None, and a peak under
    ``significance/peak_fraction`` σ: module docstring, point 1)."""
    widths, faint = [], []
    for k in range(len(np.asarray(data.scales))):
        narrowest, dim = np.inf, False
        for i in data.images_of_scale(k):
            moments = lobe_moments(data, i, thresholds)
            pitch = 2.0 * data.extents[i] / (data.image_sizes[i] - 1)
            if moments is None:
                n = data.image_sizes[i]
                snr = np.asarray(data.values[i, : n * n]) * np.asarray(data.weight[i, : n * n])
                dim |= float(np.max(snr)) < thresholds.significance / thresholds.peak_fraction
            smallest = 0.0 if moments is None else max(float(np.linalg.eigvalsh(moments[1])[0]), 0.0)
            narrowest = min(narrowest, float(np.sqrt(smallest)) / pitch)
        widths.append(float(narrowest))
        faint.append(dim)
    return widths, faint


def lobe_widths(data: Dataset, thresholds: AdequacyDefaults = ADEQUACY) -> list[float]:
    """Per scale of ``data``: the lobe's rms width along its narrower principal axis, in image
    pixel pitches ``2·extent/(n − 1)`` (the smallest over the scale's images; 0 where fewer than
    two pixels are significant; module docstring, point 1)."""
    return _widths_and_faint(data, thresholds)[0]


def _narrow(widths, faint, min_lobe_pixels: float) -> list[int]:
    """The scales whose lobe, not too faint to measure, is narrower than ``min_lobe_pixels`` image pixels."""
    return [k for k, w in enumerate(widths) if not faint[k] and w < min_lobe_pixels]


def with_adequacy_problem(outcome: dict, problem: str) -> dict:
    """``outcome`` (:meth:`Outcome.to_json`'s form, fit.json's ``outcome``) with an adequacy problem found after
    :func:`assess` — ``brdfscale fit --predict``'s scale law rejected by the fit's ΔΣ — ranked as :func:`assess`
    ranks its checks (resolution, adequacy, convergence, identifiability: the first that fails decides): an
    outcome ``"undetermined"`` by the resolution check (a scale's lobe too faint or narrower than
    ``min_lobe_pixels``, read from its rows) or already ``"inadequate"`` keeps its status and reason; ``"ok"``,
    ``"not_converged"`` and ``"undetermined"`` by identifiability become ``"inadequate"`` with ``problem`` as the
    reason. ``problem`` joins ``problems`` in every case."""
    scales = outcome.get("scales") or []
    faint = [bool(s.get("faint")) for s in scales]
    widths = [s.get("width_px") if s.get("width_px") is not None else math.inf for s in scales]
    limit = (outcome.get("thresholds") or {}).get("min_lobe_pixels", ADEQUACY.min_lobe_pixels)
    unresolved = any(faint) or bool(_narrow(widths, faint, limit))
    amended = {**outcome, "problems": [*outcome.get("problems", []), problem]}
    if outcome["status"] != "inadequate" and not (outcome["status"] == "undetermined" and unresolved):
        amended.update(status="inadequate", reason=problem)
    return amended


def resolution(data: Dataset, *, unit: str | None = None, thresholds: AdequacyDefaults = ADEQUACY) -> Outcome:
    """The resolution check alone (before a fit: a lobe narrower than ``min_lobe_pixels`` image
    pixels at any scale, or too faint to measure, makes the outcome ``"undetermined"``); ``unit``
    names μ's length unit in the reason (None: pixels of the height field). Each scale's row has
    ``faint``: fewer than two pixels above the noise (module docstring, point 1)."""
    scales = np.asarray(data.scales)
    widths, faint = _widths_and_faint(data, thresholds)
    rows = tuple({"mu": float(mu), "width_px": w, "faint": f} for mu, w, f in zip(scales, widths, faint))
    problems = []
    if any(faint):
        first = faint.index(True)
        problems.append(
            f"the lobe at {_mu_text(float(scales[first]), unit)} is too faint to measure ({sum(faint)} of "
            f"{len(faint)} scales have fewer than two pixels above {thresholds.significance:g} σ and "
            f"{thresholds.peak_fraction:g} of the peak, the peak under "
            f"{thresholds.significance / thresholds.peak_fraction:g} σ): too few counts above the noise — measure "
            "with more counts (a longer exposure; for brdfscale synth, a larger count scale in --noise); if the "
            "lobe also lies within a pixel, a smaller image extent or a finer angular resolution"
        )
    narrow = _narrow(widths, faint, thresholds.min_lobe_pixels)
    if narrow:
        worst = min(narrow, key=lambda k: widths[k])
        problems.append(
            f"the lobe at {_mu_text(float(scales[worst]), unit)} is {widths[worst]:.2g} image pixels wide (rms, "
            f"narrower axis; {len(narrow)} of {len(widths)} scales below {thresholds.min_lobe_pixels:g}): its "
            "change with scale cannot be measured — synthesise with a smaller image extent or more pixels per "
            "image (brdfscale synth), or measure with a finer angular resolution (more pixels across the lobe)"
        )
    if not problems:
        return Outcome("ok", "", (), rows, thresholds)
    return Outcome("undetermined", problems[0], tuple(problems), rows, thresholds)


def undetermined_statistics(fit: FitResult, unit: str | None = None) -> str | None:
    """The line naming the reported statistics without a standard error (module docstring,
    **Identified**), or None when every one has one."""
    unit = unit or "px"
    missing: dict[str, list[str]] = {}
    total = 0
    for d in fit.covariance_differences:
        fixed = d.get("fixed") or [[False] * 2] * 2
        for name, a, b in DIFFERENCE_ENTRIES:
            if fixed[a][b] or d["value"][a][b] is None:
                continue
            total += 1
            if d["std"][a][b] is None:
                missing.setdefault(f"ΔΣ_{name}", []).append(f"{d['mu']:.4g}")
    n_ratios = len(fit.ratios)
    ratios = [name for name, r in fit.ratios.items() if r["std"] is None]
    if not missing and not ratios:
        return None
    parts = [f"{key} at μ = {', '.join(mus)} {unit}" for key, mus in missing.items()]
    count = sum(len(mus) for mus in missing.values())
    text = f"the data do not determine {count} of {total} ΔΣ(μ0, μk) components" if missing else ""
    if missing:
        text += f" ({'; '.join(parts)})"
    if ratios:
        text += (" and " if text else "the data do not determine ") + f"{len(ratios)} of {n_ratios} ratios"
        text += f" ({', '.join(ratios[:3])}{', …' if len(ratios) > 3 else ''})"
    return (
        text + ": no standard error (Laplace; std null in fit.json) — measure more scales or more counts, "
        "or fit a model with fewer parameters"
    )


_FIGURES = ("chi2", "reduced_chi2", "chi2_p", "lag1_rows", "lag1_cols", "lag1_p")
"""A fitted scale's figures (:class:`Outcome`'s ``scales``); None where its prediction is not finite."""


_AWAY_FIGURES = ("away_share", "away_peak_offset", "away_peak_z")
"""A fitted scale's diagnosis of where its misfit lies (:func:`away_from_lobe`); None where it is not defined."""


def _box3(x: np.ndarray) -> np.ndarray:
    """The sum of ``x`` over each entry's 3 × 3 neighbourhood (zero beyond the edges)."""
    padded, (rows, cols) = np.pad(x, 1), x.shape
    return np.sum([padded[a : a + rows, b : b + cols] for a in range(3) for b in range(3)], axis=0)


def away_from_lobe(
    values: Float[ArrayLike, "n_img n_pix"],
    prediction: Float[ArrayLike, "n_img n_pix"],
    weight: Float[ArrayLike, "n_img n_pix"],
    offsets: Float[ArrayLike, "n_img n_pix 2"],
    sizes: "list[int]",
    fraction: float,
) -> dict:
    """Where a scale's misfit lies: in the lobe or away from it (:func:`assess`, module docstring, point 2).

    Over the images given (one scale's: rows of ``values``, ``prediction``, ``weight`` = 1/σ, 0 where masked,
    and the pixels' slope ``offsets``; ``sizes`` their sides n, each image's first n² entries its pixels, row
    by row), with the whitened residuals ``r = (prediction − data)/σ`` at the valid pixels:

    * ``away_share``: the part of the excess ``Σ (r² − 1)`` that lies *away from the lobe*, at the pixels where
      the model predicts less than ``fraction`` of its image's largest prediction, ``Σ_away (r² − 1) / Σ (r² −
      1)`` clipped to [0, 1]; None where the excess is not positive (nothing to place). Near 1: the model
      describes the lobe and misses something beyond it — tails, or light in places the lobe does not reach
      (satellite peaks: a surface with steps of one height puts them at the step's slope); near 0: the lobe's
      own shape is wrong.
    * ``away_peak_offset``, ``away_peak_z``: the slope offset (u_x, u_y) of the away pixel with the largest
      excess of data over model, measured over its 3 × 3 neighbourhood of away pixels, ``−Σ r/√count`` (the
      sum of independent unit normals divided by √count: itself a unit normal where the model holds), and that
      value; None without away pixels.

    Verified on lobes with a satellite peak and on a lobe of the wrong shape in tests/test_adequacy.py.

    Raises:
        InvalidInputError: arrays of other shapes, sides whose squares exceed the pixels, a ``fraction`` outside
            (0, 1).
    """
    try:
        values, prediction, weight, offsets = (np.asarray(x, float) for x in (values, prediction, weight, offsets))
        sizes = [int(n) for n in sizes]
    except (TypeError, ValueError) as err:
        raise InvalidInputError(f"away_from_lobe takes arrays of real numbers and whole image sides; {err}.") from None
    shape = values.shape
    if (
        len(shape) != 2
        or prediction.shape != shape
        or weight.shape != shape
        or offsets.shape != (*shape, 2)
        or len(sizes) != shape[0]
        or any(n < 1 or n * n > shape[1] for n in sizes)
    ):
        raise InvalidInputError(
            "away_from_lobe needs values, prediction and weight of one shape (images, pixels), offsets of that shape "
            "plus (2,), and one side n per image with n² ≤ pixels; got shapes "
            f"{values.shape}, {prediction.shape}, {weight.shape}, {offsets.shape} and sides {sizes}."
        )
    fraction = real(fraction, "fraction (of the image's largest prediction)", minimum=0.0, strict=True)
    if fraction >= 1:
        raise InvalidInputError(f"fraction must lie between 0 and 1 (exclusive); got {fraction}.")
    excess = away = 0.0
    best_z, best_u = -np.inf, None
    for i, n in enumerate(sizes):
        ok = weight[i, : n * n].reshape(n, n) > 0
        p = prediction[i, : n * n].reshape(n, n)
        with np.errstate(invalid="ignore", over="ignore"):  # a masked pixel's ∞ · 0: left out by ``ok``
            r = np.where(ok, (p - values[i, : n * n].reshape(n, n)) * weight[i, : n * n].reshape(n, n), 0.0)
        far = ok & (p < fraction * np.max(np.where(ok, p, -np.inf)))
        excess += float(np.sum(np.where(ok, r * r - 1, 0.0)))
        away += float(np.sum(np.where(far, r * r - 1, 0.0)))
        if not far.any():
            continue
        # the 3 × 3 neighbourhood sums of −r and of the count over away pixels
        box, count = _box3(np.where(far, -r, 0.0)), _box3(far.astype(float))
        z = np.where(far, box / np.sqrt(np.maximum(count, 1.0)), -np.inf)
        j = int(np.argmax(z))
        if z.flat[j] > best_z:
            best_z, best_u = float(z.flat[j]), offsets[i, j].tolist()
    return {
        "away_share": min(max(away / excess, 0.0), 1.0) if excess > 0 and np.isfinite(excess) else None,
        "away_peak_offset": best_u,
        "away_peak_z": best_z if best_u is not None else None,
    }


_MOMENT_FIGURES = ("moments_z", "moments_entry", "moments_p")
"""A fitted scale's second-moment test (:func:`_moment_misses`); None at μ0 and where it is not defined."""


def _moment_tests(n_scales: int) -> int:
    """The Bonferroni count of the second-moment test: the 3 entries (xx, xy, yy) of every coarser scale's ΔΣ."""
    return 3 * (n_scales - 1)


def _moment_misses(data: Dataset, prediction: np.ndarray, observed: list[dict], stats) -> list[dict]:
    """Per scale, the second-moment test of :func:`assess` (module docstring, point 2): ``moments_z``, the largest
    (signed) ``(ΔΣ_model − ΔΣ_data)/std`` over xx, xy, yy of the pair (μ0, μ), ``moments_entry`` its entry and
    ``moments_p`` its two-sided p-value, Bonferroni-corrected over :func:`_moment_tests`; None at μ0 and where
    either ΔΣ is not defined (a scale without light, a prediction not finite at a valid pixel). ``observed``: the
    data's own :func:`moment_covariance_differences`."""
    with np.errstate(invalid="ignore", over="ignore"):
        predicted = moment_covariance_differences(data, prediction)
    n_tests = _moment_tests(len(data.scales))
    out: list[dict] = [dict.fromkeys(_MOMENT_FIGURES)]
    for seen, model in zip(observed, predicted):
        best: dict = dict.fromkeys(_MOMENT_FIGURES)
        for name, a, b in DIFFERENCE_ENTRIES:
            v, m, s = seen["value"][a][b], model["value"][a][b], seen["std"][a][b]
            if v is None or m is None or not s:
                continue
            z = (m - v) / s
            if best["moments_z"] is None or abs(z) > abs(best["moments_z"]):
                best = {"moments_z": z, "moments_entry": name, "moments_p": None}
        if best["moments_z"] is not None:
            best["moments_p"] = min(1.0, 2 * float(stats.norm.sf(abs(best["moments_z"]))) * n_tests)
        out.append(best)
    return out


def _away_text(row: dict, thresholds: AdequacyDefaults) -> str:
    """The verdict's clause on where the misfit lies (:func:`away_from_lobe`), when more than
    ``away_verdict_share`` of the failing scale's χ² excess is away from the lobe ("" otherwise)."""
    share, u, z = row["away_share"], row["away_peak_offset"], row["away_peak_z"]
    if share is None or share <= thresholds.away_verdict_share or u is None:
        return ""
    return (
        f"; {share:.0%} of the scale's χ² excess lies where the model predicts < {thresholds.away_fraction:g} of its "
        f"peak, the largest at slope offset ({u[0]:+.3g}, {u[1]:+.3g}) ({z:.3g} σ): tails or light away from the lobe "
        "that the model does not have (steps of one height in a surface put satellite peaks at their slope)"
    )


def lag1_correlation(
    residuals: Float[ArrayLike, "*shape"], valid: Bool[ArrayLike, "*shape"], axis: int
) -> tuple[float, int]:
    """The lag-1 autocorrelation of ``residuals`` along ``axis`` over neighbouring valid pairs, and the pair count:
    :func:`assess`'s statistic of residual structure (module docstring, point 2).

    With ``(x_j, y_j) = (r_j, r_{j+1})`` every pair of neighbours along ``axis`` that are both ``valid``,
    ``ρ = Σ x_j y_j / √(Σ x_j² · Σ y_j²)`` (the normalised cross product, so |ρ| ≤ 1 by Cauchy–Schwarz; ρ = 0 and
    0 pairs when no pair is valid, and ρ = 0 when every paired residual is 0). For independent zero-mean residuals
    ``ρ·√pairs`` is standard normal. Verified against a NumPy loop over the pairs in tests/test_adequacy.py, and its
    false-alarm rate and power through :func:`assess` there too.

    Args:
        residuals: whitened residuals ``(prediction − data)/σ`` of an image (leading axes: several images).
        valid: the pixels that count, the same shape.
        axis: the axis along which neighbours are paired (of an image: 1 along its rows, 0 along its columns).

    Raises:
        InvalidInputError: shapes that differ, or an axis the arrays do not have.
    """
    r, ok = np.asarray(residuals, float), np.asarray(valid, bool)
    if r.shape != ok.shape or r.ndim < 1 or isinstance(axis, bool) or not isinstance(axis, (int, np.integer)):
        raise InvalidInputError(
            f"residuals and valid must be arrays of one shape and axis an integer; got shapes {r.shape} and "
            f"{ok.shape}, axis {axis!r}."
        )
    if not -r.ndim <= axis < r.ndim:
        raise InvalidInputError(f"axis must be one of the arrays' {r.ndim} axes; got {axis}.")
    a, b = (np.moveaxis(x, int(axis), -1) for x in (r, ok))
    pairs = b[..., :-1] & b[..., 1:]
    n = int(np.count_nonzero(pairs))
    if n == 0:
        return 0.0, 0
    x, y = a[..., :-1][pairs], a[..., 1:][pairs]
    scale = np.sqrt(np.sum(x * x) * np.sum(y * y))
    return (float(np.sum(x * y) / scale) if scale > 0 else 0.0), n


def assess(
    problem: Problem,
    fit: FitResult,
    samples=None,
    *,
    unit: str | None = None,
    thresholds: AdequacyDefaults = ADEQUACY,
    covariance_truth: list | None = None,
) -> Outcome:
    """Resolution, model adequacy and convergence of a fit (module docstring); returns the :class:`Outcome`.

    Args:
        problem: the fit's problem.
        fit: its :class:`FitResult`.
        samples: its :class:`SampleResult` when sampled (None: the optimiser's status only).
        unit: μ's length unit for the reason (None: pixels of the height field).
        thresholds: :class:`brdfscale.choices.AdequacyDefaults` (default ``ADEQUACY``).
        covariance_truth: the true ΔΣ(μ0, μ_k) where known (:func:`fitting.covariance_truth` of a synthesised set's
            metadata): the fit's ΔΣ is then tested against it too (module docstring, point 2).

    Raises:
        InvalidInputError: ``fit`` does not belong to ``problem``.
    """
    return assess_against(
        problem,
        fit,
        samples,
        unit=unit,
        thresholds=thresholds,
        observed_moments=None,
        covariance_truth=covariance_truth,
    )


def _truth_miss(fit: FitResult, covariance_truth, unit, thresholds: AdequacyDefaults, stats) -> tuple | None:
    """The fit's ΔΣ against a known truth (module docstring, point 2): ``(severity, line, "")`` where the largest
    |pull| fails the Bonferroni-corrected test, None where it passes or there is nothing to test."""
    if covariance_truth is None:
        return None
    expected = (len(fit.covariance_differences), 2, 2)
    try:
        values = np.asarray(covariance_truth, dtype=float)
    except (TypeError, ValueError):
        values = None
    if values is None or values.shape != expected or not np.all(np.isfinite(values)):
        raise InvalidInputError(
            f"covariance_truth must be the true ΔΣ(μ0, μk) of every coarser scale, {expected[0]} finite 2 × 2 "
            f"matrices (fitting.covariance_truth of the set's metadata), or None; got {covariance_truth!r:.80}."
        )
    entries = compare_covariance_differences(fit.covariance_differences, covariance_truth)
    pulls = [
        (abs(pull[i][j]), pull[i][j], name, entry["mu"])
        for entry in entries
        if (pull := entry.get("pull")) is not None
        for name, i, j in DIFFERENCE_ENTRIES
        if pull[i][j] is not None
    ]
    if not pulls:
        return None
    size, z, name, mu = max(pulls)
    p = min(1.0, 2 * float(stats.norm.sf(size)) * len(pulls))
    if p >= thresholds.p_value:
        return None
    limit = float(stats.norm.isf(thresholds.p_value / (2 * len(pulls))))
    line = (
        f"model inadequate at {_mu_text(float(mu), unit)}: its ΔΣ_{name}(μ0, μ) is {z:+.3g} standard errors off the "
        f"truth the file records (fitting.covariance_truth; p = {p:.2g} over {len(pulls)} entries): its error bars "
        "do not cover the surface — the model misses what the images hold of it (tails below the noise or past the "
        "image's edge, masking; the images' own ΔΣ, model-free: fit.json's moment_covariance_differences)"
    )
    return size / limit, line, ""


def assess_against(
    problem: Problem,
    fit: FitResult,
    samples=None,
    *,
    unit: str | None,
    thresholds: AdequacyDefaults,
    observed_moments: list[dict] | None,
    covariance_truth: list | None = None,
) -> Outcome:
    """:func:`assess` with the data's own :func:`moment_covariance_differences` given where the caller has them
    (:func:`fitting.write_report` writes them to fit.json too: computed once); None computes them."""
    from scipy import stats  # here, not at import: scipy.stats costs ~0.7 s of every command's start

    check_fit(problem, fit, "assess(problem, fit)")
    data, model = problem.data, problem.model
    theta = jnp.clip(jnp.asarray(fit.theta), problem.lower, problem.upper)
    weight = np.asarray(data.weight)
    valid_pixels = weight > 0
    # masked pixels (weight 0) are left out, whatever the model predicts there (∞ · 0 would be NaN)
    prediction = np.asarray(predict_images(model, theta, data))
    values, offsets = np.asarray(data.values), np.asarray(data.offsets)  # once, not per scale
    with np.errstate(invalid="ignore", over="ignore"):
        residual = (prediction - values) * weight
    whitened = np.where(valid_pixels, residual, 0.0)
    scales = np.asarray(data.scales)
    resolved = resolution(data, unit=unit, thresholds=thresholds)
    n_total, p = max(data.n_data, 1), len(fit.names)
    n_tests = 2 * len(data.scale_of_image)
    if observed_moments is None:
        observed_moments = moment_covariance_differences(data)
    moments = _moment_misses(data, np.where(valid_pixels, prediction, 0.0), observed_moments, stats)
    rows, inadequate = [], []
    for k, mu in enumerate(scales):
        images = data.images_of_scale(k)
        n_k = int(np.count_nonzero(valid_pixels[images]))
        dof = max(n_k - p * n_k / n_total, 1.0)
        where = _mu_text(float(mu), unit)
        undefined = int(np.count_nonzero(~np.isfinite(whitened[images])))
        if undefined:  # no χ² and no autocorrelation: the scale's figures are None (null), never NaN
            rows.append({**resolved.scales[k], "dof": dof, **dict.fromkeys(_FIGURES + _MOMENT_FIGURES + _AWAY_FIGURES)})
            inadequate.append(
                (
                    np.inf,
                    f"model inadequate at {where}: its prediction is not finite at {undefined} of the {n_k} valid "
                    "pixels (χ² undefined)",
                    "",
                )
            )
            continue
        chi2 = float(np.sum(whitened[images] ** 2))
        lag = {0: 0.0, 1: 0.0}
        p_lag = 1.0
        for i in images:
            n = data.image_sizes[i]
            r, valid = whitened[i, : n * n].reshape(n, n), weight[i, : n * n].reshape(n, n) > 0
            for axis in (0, 1):
                rho, pairs = lag1_correlation(r, valid, axis)
                lag[axis] = max(lag[axis], rho)
                if pairs:
                    p_lag = min(p_lag, float(stats.norm.sf(rho * np.sqrt(pairs))) * n_tests)
        row = {
            **resolved.scales[k],
            "chi2": chi2,
            "dof": dof,
            "reduced_chi2": chi2 / dof,
            "chi2_p": float(stats.chi2.sf(chi2, dof)),
            "lag1_rows": lag[1],
            "lag1_cols": lag[0],
            "lag1_p": min(p_lag, 1.0),
            **moments[k],
            **away_from_lobe(
                values[images],
                prediction[images],
                weight[images],
                offsets[images],
                [data.image_sizes[i] for i in images],
                thresholds.away_fraction,
            ),
        }
        rows.append(row)
        away = _away_text(row, thresholds)  # on the headline only: where the worst scale's misfit lies
        if row["reduced_chi2"] > thresholds.max_reduced_chi2 and row["chi2_p"] < thresholds.p_value:
            inadequate.append(
                (
                    row["reduced_chi2"] / thresholds.max_reduced_chi2,
                    f"model inadequate at {where}: χ²/dof = {row['reduced_chi2']:.3g} "
                    f"(> {thresholds.max_reduced_chi2:g}, p = {row['chi2_p']:.2g})",
                    away,
                )
            )
        if row["moments_p"] is not None and row["moments_p"] < thresholds.p_value:
            z, entry = row["moments_z"], row["moments_entry"]
            inadequate.append(
                (
                    abs(z) / float(stats.norm.isf(thresholds.p_value / (2 * _moment_tests(len(scales))))),
                    f"model inadequate at {where}: its images' second moments miss the data's — ΔΣ_{entry}(μ0, μ) "
                    f"of its lobes over the images' pixels is {z:+.3g} standard errors off the images' own "
                    f"(p = {row['moments_p']:.2g}): the lobes' tails are not the model's shape "
                    "(the images' own ΔΣ: fit.json's moment_covariance_differences)",
                    away,
                )
            )
        largest = max(lag.values())
        if largest > thresholds.max_lag1 and row["lag1_p"] < thresholds.p_value:
            direction = "rows" if lag[1] >= lag[0] else "columns"
            inadequate.append(
                (
                    largest / thresholds.max_lag1,
                    f"model inadequate at {where}: residual structure, lag-1 autocorrelation of the whitened "
                    f"residuals along the {direction} {largest:.2f} "
                    f"(> {thresholds.max_lag1:g}, p = {row['lag1_p']:.2g})",
                    away,
                )
            )
    problems = list(resolved.problems)
    inadequate.sort(key=lambda item: -item[0])
    # after the images' own tests, whatever its size: a failed test of the images says where the model misses
    truth_miss = _truth_miss(fit, covariance_truth, unit, thresholds, stats)
    if truth_miss is not None:
        inadequate.append(truth_miss)
    advice = (
        " — compare other lobe shapes and models (fitting.compare; brdfscale fit --compare, --shape, --increments, "
        "--model)"
    )
    problems += [text + away + advice for _, text, away in inadequate[:1]]
    problems += [text for _, text, _ in inadequate[1:]]
    if fit.status != "converged":
        problems.append(
            f"not converged: the optimiser's best start ended with {fit.status} (allow the solver more steps)"
        )
    if samples is not None and samples.status != "converged":
        problems.append(f"sampler {samples.status} (sample longer)")
    stalled = fit.status != "converged" or (samples is not None and samples.status != "converged")
    unidentified = undetermined_statistics(fit, unit)
    problems += [unidentified] if unidentified else []
    status: Status = (
        "ok"
        if not problems
        else "undetermined"
        if not resolved.ok
        else "inadequate"
        if inadequate
        else "not_converged"
        if stalled
        else "undetermined"
    )
    return Outcome(status, problems[0] if problems else "", tuple(problems), tuple(rows), thresholds)
