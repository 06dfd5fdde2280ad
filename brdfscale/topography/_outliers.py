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
    ``robust_sd``: 1.4826 × the median absolute deviation, or — where more than half of the slopes equal their
    median (a quantised, smooth field: MAD 0) — the smallest nonzero |m − median| (one slope quantum);
    ``step``: the common height step of the outliers, ``median |m − median(m)| · Δ`` in ``unit`` (the field's
    length unit: metres for a measured field), where there are :data:`MIN_STEP_OUTLIERS` or more and at least
    half of them lie within :data:`STEP_TOLERANCE` of that median deviation — steps of one height between
    neighbouring pixels (None otherwise); ``step_share``: that half-or-more's share of the outliers (0 without a
    step).
    """

    threshold: float
    fraction: tuple[float, float]
    variance_share: tuple[float, float]
    robust_sd: tuple[float, float]
    step: tuple[float | None, float | None]
    step_share: tuple[float, float]
    unit: str | None = None

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
                unit = self.unit or "(the field's length unit)"
                text += f" ({100 * self.step_share[a]:.0f} % of those: steps of {self.step[a]:.3g} {unit})"
            axes.append(text)
        return (
            f"note: {'; '.join(axes)} (beyond {self.threshold:g} robust σ of the median): Σ(μ) and ΔΣ are theirs — "
            "spikes, steps or instrument artefacts more than the texture; lobes of this surface have faint wide "
            "tails or satellite peaks at those slopes, which no lobe model here has"
        )

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, record: dict) -> "SlopeOutliers":
        """The inverse of :meth:`to_json` (JSON's lists back to pairs; a record without ``unit`` has None).

        Raises:
            InvalidInputError: ``record`` is not such a record (a key missing, not a pair of numbers, or a
                threshold that is not a number), naming what is wrong.
        """

        def pair(key: str, optional: bool = False) -> tuple:
            value = record[key]
            if not isinstance(value, (list, tuple)) or len(value) != 2:
                raise TypeError(key)
            return tuple(None if optional and v is None else float(v) for v in value)

        try:
            return cls(
                threshold=float(record["threshold"]),
                fraction=pair("fraction"),
                variance_share=pair("variance_share"),
                robust_sd=pair("robust_sd"),
                step=pair("step", optional=True),
                step_share=pair("step_share"),
                unit=record.get("unit"),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise InvalidInputError(
                f"a damaged slope-outlier record ({type(error).__name__}: {error}): expected the keys threshold, "
                "fraction, variance_share, robust_sd, step, step_share (pairs x, y of numbers; step's may be null) "
                "as SlopeOutliers.to_json writes them; make it again: topography.slope_outliers(field).to_json()."
            ) from None


def slope_outliers(field: HeightField, threshold: float = OUTLIER_THRESHOLD) -> SlopeOutliers:
    """The pixel slopes of ``field`` beyond ``threshold`` robust standard deviations of their median, per axis,
    and the share of the slope variance they carry (:class:`SlopeOutliers`).

    A measured surface's Σ(μ) is a second moment: a few steep pixels — spikes, steps of one height (an
    interferometer's phase jumps), dropouts at edges — can carry nearly all of it, and then Σ(μ), ΔΣ and their
    standard errors describe those pixels, not the texture. Lobes synthesised from such a field hold them as
    faint tails or satellite peaks beyond the lobe (``fitting.assess``'s ``away_share``), and a fit's ΔΣ, which
    follows the lobe's core, cannot meet the field's. On tests/data (x / y): mnt-1's outliers, 0.69 % / 0.97 %
    of the pixel slopes, carry 99.4 % / 97.9 % of the variance, 65 % / 97 % of them steps of 0.30 / 0.29 µm;
    frt-1's, 0.91 % / 0.91 %, carry 98 % / 97.6 %; mi-1's, 1.7 % / 0.97 %, carry 49 % / 82 %
    (tests/test_topography.py, which also checks a field of known steps, square and rectangular pixels, against
    the closed form).

    Raises:
        InvalidInputError: ``field`` not a :class:`brdfscale.synth.HeightField`; ``threshold`` not a positive
            number.
    """
    slopes = pixel_slopes(field)  # refuses what is not a HeightField, naming what is accepted
    threshold = real(threshold, "threshold (robust standard deviations)", minimum=0.0, strict=True)
    out: dict[str, list] = {k: [] for k in ("fraction", "variance_share", "robust_sd", "step", "step_share")}
    for a, pitch in enumerate(field.spacing):  # component a of the slopes is along x (a = 0) or y, pitch Δx or Δy
        m = slopes[..., a][np.isfinite(slopes[..., a])]
        if m.size == 0:
            for key, empty in (("fraction", 0.0), ("variance_share", 0.0), ("robust_sd", 0.0), ("step", None)):
                out[key].append(empty)
            out["step_share"].append(0.0)
            continue
        deviation = np.abs(m - np.median(m))
        sd = 1.4826 * float(np.median(deviation))
        if sd == 0 and np.any(deviation > 0):  # over half of the slopes equal their median: one quantum instead
            sd = float(np.min(deviation[deviation > 0]))
        far = deviation > threshold * sd
        spread = (m - m.mean()) ** 2
        total = float(np.sum(spread))
        step, share = None, 0.0
        if np.count_nonzero(far) >= MIN_STEP_OUTLIERS:
            typical = float(np.median(deviation[far]))
            near = np.abs(deviation[far] - typical) <= STEP_TOLERANCE * typical
            if near.mean() >= 0.5 and typical > 0:
                step, share = typical * pitch, float(near.mean())
        out["fraction"].append(float(far.mean()))
        out["variance_share"].append(float(np.sum(spread[far])) / total if total > 0 else 0.0)
        out["robust_sd"].append(sd)
        out["step"].append(step)
        out["step_share"].append(share)
    return SlopeOutliers(threshold, **{k: tuple(v) for k, v in out.items()}, unit=field.unit)
