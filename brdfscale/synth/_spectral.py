"""Gaussian random height fields by spectral synthesis."""

import equinox as eqx
import numpy as np

from .. import stats
from .._errors import InvalidInputError
from .._validation import integer, real
from ._random import as_generator, seed_record
from ._surface import check_grid, check_micro, HeightField, parameter_record


_ROWS_PER_CHUNK = 256


@eqx.filter_jit
def _evaluate(spectrum, k):
    return spectrum(k)


def _check_size(size) -> int:
    """Pixels per side of a synthesised field: an integer ≥ 4 (not a float) within MAX_GRID_BYTES."""
    n = integer(size, "size (pixels per side)", 4)
    check_grid(n, f"a height field of size={n}", "synthesise smaller tiles (a smaller size)")
    return n


def spectral_field(
    spectrum: stats.AbstractPowerSpectrum,
    *,
    size: int,
    spacing: float = 1.0,
    seed,
    micro: stats.AbstractSlopeDensity | None = None,
) -> HeightField:
    """A periodic Gaussian random height field with power spectrum ``P = spectrum(k)``.

    White noise ``w`` (unit variance per pixel) is filtered in Fourier space:
    ``h = IDFT(DFT(w) · √P(k) / Δ)`` on the wave vectors ``k = 2π n / (N Δ)`` of the
    periodic ``N × N`` grid. With :class:`brdfscale.stats.AbstractPowerSpectrum`'s
    normalisation ``∫ P d²k / (2π)² = ⟨h²⟩`` this gives ``⟨|ĥ(k)|²⟩ = P(k)`` per Fourier
    mode, i.e. the field's covariance is the spectrum's, restricted to the grid's band
    ``|k_x|, |k_y| ≤ π/Δ`` (power beyond the Nyquist wavenumber is absent — choose Δ small
    against the correlation length). The k = 0 mode is set to zero: the mean height is 0.

    ``GaussianCorrelation`` with a pair of correlation lengths gives an anisotropic field;
    ``KCorrelation`` a fractal (ABC) one. Memory: the noise, its half-spectrum and the
    result, about ``3 × 8 N²`` bytes (0.4 GB at N = 4096); the spectrum is evaluated in
    strips of rows. The heights (``8 N²`` bytes) must fit :data:`MAX_GRID_BYTES` (2**31
    bytes, N ≤ 16384): a larger ``size`` is refused before anything is allocated —
    synthesise smaller tiles instead.

    Args:
        spectrum: a :mod:`brdfscale.stats` power spectrum (``GaussianCorrelation``, ``KCorrelation``).
        size: N, pixels per side (≥ 4).
        spacing: the pixel pitch Δ (length units of the spectrum).
        seed: an int, a NumPy ``Generator`` or a JAX PRNG key (see :func:`as_generator`).
        micro: the pixel facets' lobe; default mirror (``stats.Delta()``).

    Raises:
        InvalidInputError: a spectrum that is not a :mod:`brdfscale.stats` power spectrum;
            ``size`` not an integer ≥ 4 (a float such as 256.0 is refused) or above
            :data:`MAX_GRID_BYTES`; ``spacing`` not a positive real number; a bad seed; a
            ``micro`` that is not a probability density of facet slopes.
    """
    if not isinstance(spectrum, stats.AbstractPowerSpectrum):
        raise InvalidInputError(
            "spectrum must be a brdfscale.stats power spectrum (GaussianCorrelation, KCorrelation); "
            f"got {type(spectrum).__name__}."
        )
    n = _check_size(size)
    spacing = real(spacing, "spacing (the pixel pitch)", minimum=0, strict=True)
    micro = stats.Delta() if micro is None else check_micro(micro)
    rng = as_generator(seed)
    noise_hat = np.fft.rfft2(rng.standard_normal((n, n)))
    ky = 2 * np.pi * np.fft.fftfreq(n, spacing)
    kx = 2 * np.pi * np.fft.rfftfreq(n, spacing)
    for start in range(0, n, _ROWS_PER_CHUNK):
        rows = slice(start, min(start + _ROWS_PER_CHUNK, n))
        k = np.stack(np.broadcast_arrays(kx[None, :], ky[rows, None]), axis=-1)
        power = np.asarray(_evaluate(spectrum, k), dtype=float)
        if not np.all(np.isfinite(power) & (power >= 0)):
            raise InvalidInputError("spectrum(k) must be finite and non-negative on the grid's wave vectors.")
        noise_hat[rows] *= np.sqrt(power) / spacing
    noise_hat[0, 0] = 0.0
    heights = np.fft.irfft2(noise_hat, s=(n, n))
    description = {
        "generator": "spectral_field",
        "spectrum": parameter_record(spectrum),
        "size": n,
        "spacing": float(spacing),
        "seed": seed_record(seed),
    }
    return HeightField(heights, spacing, micro=micro, spectrum=spectrum, description=description)
