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
* :func:`detrend` — the explicit, recorded removal of a plane or a quadratic.

Conventions (docs/topography.md): heights and lengths in **metres**; rows are y, columns
are x (SurfaceTopography's ``heights()`` is indexed ``[x, y]``; :func:`read` transposes);
the mask is True where a height was measured; a measured field is not periodic, so
its facet windows are placed without wrap-around and those touching an unmeasured pixel
are excluded. Provenance — file, format, instrument, channel, units, the detrending and its
coefficients — is in ``field.description``.
"""

from ._array import detrend, DETRENDS, from_array, UNITS
from ._read import read


__all__ = ["read", "from_array", "detrend", "DETRENDS", "UNITS"]
