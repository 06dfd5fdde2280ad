"""Measured surfaces: height maps from instrument files or arrays, as :class:`brdfscale.synth.HeightField`.

A measured height map — from an AFM, an interferometer, a confocal microscope, a stylus or
optical profilometer — enters brdfscale here and is from then on a
:class:`~brdfscale.synth.HeightField` like any synthesised one: :func:`brdfscale.synth.facet_statistics`
measures its scale-dependent slope statistics ``s(·, μ)``, ``Σ(μ)`` and within-facet lobes
``g_μ`` (seed §3–4), :func:`brdfscale.synth.gonioreflectometer` makes a multi-scale
measurement set of it, and ``brdfscale fit`` fits that.

* :func:`read` — an instrument file through SurfaceTopography (some thirty formats; the
  optional extra ``pip install "brdfscale[topography]"``);
* :func:`from_array` — your own array of heights, with its pixel pitch, unit and mask;
* :func:`detrend` — the explicit, recorded removal of a plane or a quadratic;
* :func:`resample` — a field onto square pixels (separable cubic convolution, recorded);
* :func:`height_quantum` — the instrument's height step, where its heights lie on a lattice (recorded);
* :func:`slope_outliers` — the few pixel slopes that can carry nearly all of Σ (spikes, steps of one height).

Damaged files: every failure of SurfaceTopography's readers becomes a
:class:`brdfscale.MeasurementFileError` naming the file and the reason, and so does a height
map whose pitch lies outside :data:`PITCH_RANGE_M` or whose steepest slope lies outside the
range a surface has (docs/robustness.md, "Instrument files"). Pitches equal to a relative
1e-3 are made square and the difference recorded (:func:`square_pitch`).

Conventions (docs/topography.md): heights and lengths in **metres**; rows are y, columns
are x (SurfaceTopography's ``heights()`` is indexed ``[x, y]``; :func:`read` transposes);
the mask is True where a height was measured; a measured field is not periodic, so
its facet windows are placed without wrap-around and those touching an unmeasured pixel
are excluded. Provenance — file, format, instrument, channel, units, the detrending and its
coefficients — is in ``field.description``.
"""

from ._array import (
    detrend,
    DETRENDS,
    from_array,
    height_quantum,
    PITCH_RANGE_M,
    PLANE_ROUNDING,
    QUANTISED_DISTINCT,
    square_pitch,
    UNITS,
)
from ._outliers import OUTLIER_THRESHOLD, slope_outliers, SlopeOutliers
from ._read import read
from ._resample import INTERPOLATION, resample


__all__ = [
    "read",
    "from_array",
    "detrend",
    "resample",
    "square_pitch",
    "height_quantum",
    "slope_outliers",
    "SlopeOutliers",
    "OUTLIER_THRESHOLD",
    "QUANTISED_DISTINCT",
    "PLANE_ROUNDING",
    "DETRENDS",
    "UNITS",
    "PITCH_RANGE_M",
    "INTERPOLATION",
]
