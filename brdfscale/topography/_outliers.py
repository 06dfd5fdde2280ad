"""Slope outliers: how much of a measured surface's slope variance a few pixels carry (:func:`slope_outliers`)."""

import dataclasses

import numpy as np

from .._errors import InvalidInputError
from .._validation import real
from ..synth import HeightField, pixel_slopes


__all__ = ["OUTLIER_THRESHOLD", "SlopeOutliers", "slope_outliers"]

OUTLIER_THRESHOLD = 10.0
"""A pixel slope component is an outlier beyond this many robust standard deviations (1.4826 × MAD) from the
median: 10 robust σ lie ~10 standard deviations out on Gaussian slopes (a share of 1e-23), so every outlier
of a Gaussian-like texture is a feature, not its tail."""

DOMINATED = 0.5
"""The note of :meth:`SlopeOutliers.note`: outliers that carry more than this share of an axis's slope variance."""

STEP_TOLERANCE = 0.1
"""Outliers form *one step* when at least half of them lie within this relative distance of their median |m|."""

MIN_STEP_OUTLIERS = 10
"""Fewer outliers than this are not tested for one step (a handful of pixels agree by chance)."""


@dataclasses.dataclass(frozen=True)
class SlopeOutliers:
    """Per axis (x, y): the pixel slopes beyond ``threshold`` robust standard deviations of the median, and what
    they carry (:func:`slope_outliers`).

    ``fraction``: their share of the measured pixel facets; ``variance_share``: their share of the slope
    variance ``Σ(|m − m̄|²)`` (about the mean of all, so the shares of outliers and the rest add to 1);
    ``robust_sd``: 1.4826 × the median absolute deviation; ``step``: the common height step of the outliers,
    ``median |m| · Δ`` (metres), where there are :data:`MIN_STEP_OUTLIERS` or more and at least half of them
    lie within :data:`STEP_TOLERANCE` of their median |m| — steps of one height between neighbouring pixels
    (None otherwise); ``step_share``: that half-or-more's share of the outliers (0 without a step).
    """

    threshold: float
    fraction: tuple[float, float]
    variance_share: tuple[float, float]
    robust_sd: tuple[float, float]
    step: tuple[float | None, float | None]
    step_share: tuple[float, float]

    @property
    def dominated(self) -> bool:
        """The outliers carry more than :data:`DOMINATED` of the slope variance along an axis."""
        return max(self.variance_share) > DOMINATED

    def note(self) -> str | None:
        """One line for a person, where the outliers dominate (None otherwise)."""
        if not self.dominated:
            return None
        axes = []
        for a, name in enumerate("xy"):
            text = (
                f"{100 * self.fraction[a]:.2g} % of the pixel slopes along {name} carry "
                f"{100 * self.variance_share[a]:.3g} % of their variance"
            )
            if self.step[a] is not None:
                text += f" ({100 * self.step_share[a]:.0f} % of those: steps of {self.step[a]:.3g} m)"
            axes.append(text)
        return (
            f"note: {'; '.join(axes)} (beyond {self.threshold:g} robust σ of the median): Σ(μ) and ΔΣ are theirs — "
            "spikes, steps or instrument artefacts more than the texture; lobes of this surface have faint wide "
            "tails or satellite peaks at those slopes, which no lobe model here has"
        )

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def slope_outliers(field: HeightField, threshold: float = OUTLIER_THRESHOLD) -> SlopeOutliers:
    """The pixel slopes of ``field`` beyond ``threshold`` robust standard deviations of their median, per axis,
    and the share of the slope variance they carry (:class:`SlopeOutliers`).

    A measured surface's Σ(μ) is a second moment: a few steep pixels — spikes, steps of one height (an
    interferometer's phase jumps), dropouts at edges — can carry nearly all of it, and then Σ(μ), ΔΣ and their
    standard errors describe those pixels, not the texture. Lobes synthesised from such a field hold them as
    faint tails or satellite peaks beyond the lobe (``fitting.assess``'s ``away_share``), and a fit's ΔΣ, which
    follows the lobe's core, cannot meet the field's. On tests/data: mnt-1's outliers (under 1 % of the pixels)
    carry 98–99 % of the variance, mostly steps of 0.30 µm (65 % of them along x, 97 % along y); frt-1's 98 %;
    mi-1's 49 % and 82 % (tests/test_topography.py, with a field of known steps against the closed form).

    Raises:
        InvalidInputError: ``field`` not a HeightField; ``threshold`` not a positive number.
    """
    if not isinstance(field, HeightField):
        raise InvalidInputError(f"field must be a brdfscale.synth.HeightField; got {type(field).__name__}.")
    threshold = real(threshold, "threshold")
    if not threshold > 0:
        raise InvalidInputError(f"threshold must be a positive number of robust standard deviations; got {threshold}.")
    slopes = pixel_slopes(field)
    out: dict[str, list] = {k: [] for k in ("fraction", "variance_share", "robust_sd", "step", "step_share")}
    for a, pitch in enumerate(field.spacing):
        m = slopes[..., a][np.isfinite(slopes[..., a])]
        median = float(np.median(m)) if m.size else 0.0
        sd = 1.4826 * float(np.median(np.abs(m - median))) if m.size else 0.0
        far = np.abs(m - median) > threshold * sd if sd > 0 else m != median
        deviation = (m - m.mean()) ** 2 if m.size else m
        total = float(np.sum(deviation))
        step, share = None, 0.0
        if np.count_nonzero(far) >= MIN_STEP_OUTLIERS:
            size = np.abs(m[far])
            typical = float(np.median(size))
            near = np.abs(size - typical) <= STEP_TOLERANCE * typical
            if near.mean() >= 0.5 and typical > 0:
                step, share = typical * pitch, float(near.mean())
        out["fraction"].append(float(far.mean()) if m.size else 0.0)
        out["variance_share"].append(float(np.sum(deviation[far])) / total if total > 0 else 0.0)
        out["robust_sd"].append(sd)
        out["step"].append(step)
        out["step_share"].append(share)
    return SlopeOutliers(threshold, **{k: tuple(v) for k, v in out.items()})
