"""Names and descriptions of the built-in surfaces (no JAX: the command line's help reads them).

The builders are in :mod:`brdfscale.synth._named`, which pairs each name with its builder.
"""

DESCRIPTIONS: dict[str, str] = {
    "gaussian": "Gaussian-correlated, σ_h = 0.05, ℓ = 8 px (rms slope per axis 0.0088)",
    "anisotropic": "Gaussian-correlated, σ_h = 0.05, ℓ = (6, 24) px",
    "fractal": "K-correlation (ABC) fractal, A = 30, B = 32 px, C = 3.5",
    "scratched": "Gaussian σ_h = 0.02, ℓ = 8 px, plus size/32 V-scratches 0.2 deep, 8 px wide",
    "blazed": "blazed grating, period 16 px, 75 % of facets at slope +0.03, 25 % at −0.09",
}
