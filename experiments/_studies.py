"""Shared code of the studies (consistency, evolution accuracy, validity, rendering).

Conventions are the library's (docs/conventions.md §1, docs/synth_exr.md): heights ``h[j, k]`` at
``(x, y) = (kΔ, jΔ)``, pixel facets with forward-difference normal slopes ``m = −∇h``,
facets at scale μ are ``b × b`` pixel blocks (``b = μ/Δ``). Everything here is NumPy: the
studies post-process histograms of millions of samples, which gains nothing from tracing.
"""

import json
import os
from pathlib import Path

import numpy as np

import brdfscale as bs
from brdfscale import files
from experiments._bench import machine, RESULTS


WINDOWS = ("box", "gaussian", "spectral")
"""Facet windows: the b×b block mean (the library's), a Gaussian of the box's second moment
(σ = b/√12 per axis, centred on the block) and an ideal low-pass (|k_x|, |k_y| < π/b)."""


# -- files -----------------------------------------------------------------------------------


def study_dir(study: str, out: str | os.PathLike | None = None) -> Path:
    """``experiments/results/<study>/`` (or ``out``), created."""
    path = Path(out) if out is not None else RESULTS / study
    path.mkdir(parents=True, exist_ok=True)
    return path


def atomic_write(path: Path, write) -> Path:
    """Write ``path`` through ``write(tmp)`` atomically, replacing an earlier result."""
    files.atomic_write(path, write, overwrite=True)
    return path


def write_results(directory: Path, name: str, payload: dict) -> Path:
    """``directory/<name>.json`` written atomically, with the machine description added."""
    payload = {"machine": machine(), **payload}

    path = directory / f"{name}.json"
    files.write_text(path, json.dumps(payload, indent=2) + "\n", overwrite=True)
    return path


def save_figure(fig, path: Path) -> Path:
    """Save a matplotlib figure atomically and close it."""
    import matplotlib.pyplot as plt

    def write(tmp):
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format=path.suffix[1:])

    atomic_write(path, write)
    plt.close(fig)
    return path


def progress(iterable, **kw):
    """The library's progress bar (:func:`brdfscale.show.progress_bar`: text on stderr, the
    notebook widget in Jupyter; none with ``BRDFSCALE_PROGRESS=0``)."""
    from brdfscale.show import progress_bar

    return progress_bar(iterable, mininterval=1.0, **kw)


# -- surfaces and facet slopes -------------------------------------------------------------


def pixel_slopes(heights: np.ndarray, spacing: float = 1.0) -> np.ndarray:
    """Normal slopes ``m = −∇h`` of the pixel facets (periodic forward differences), (n, n, 2)."""
    mx = -(np.roll(heights, -1, axis=1) - heights) / spacing
    my = -(np.roll(heights, -1, axis=0) - heights) / spacing
    return np.stack([mx, my], axis=-1)


def window_slopes(m: np.ndarray, b: int, window: str) -> np.ndarray:
    """Facet slopes at scale b (pixels) with a facet window, shape ``(n//b, n//b, 2)``.

    Facet ``[J, K]`` owns the pixels of block ``J b … J b + b − 1`` × ``K b … K b + b − 1``
    (``b`` must divide n). ``"box"``: the block mean of the pixel slopes (equals
    :func:`brdfscale.synth.facet_slopes`). ``"gaussian"``: the pixel slopes filtered with a
    periodic Gaussian of standard deviation ``b/√12`` per axis, read at the block centre.
    ``"spectral"``: the ideal low-pass keeping ``|k_x|, |k_y| < π/b`` (the band a grid of
    facets of pitch b can carry), read at the block centre. The last two are FFT filters
    of the periodic field; the centre ``(b − 1)/2`` is reached by a phase shift.
    """
    n = m.shape[0]
    if n % b:
        raise ValueError(f"facet size {b} must divide the field size {n}")
    nb = n // b
    if window == "box":
        return m.reshape(nb, b, nb, b, 2).mean(axis=(1, 3))
    k = 2 * np.pi * np.fft.fftfreq(n)
    kx, ky = k[None, :], k[:, None]
    if window == "gaussian":
        transfer = np.exp(-(kx**2 + ky**2) * b**2 / 24)  # σ² = b²/12, exp(−σ²k²/2)
    elif window == "spectral":
        transfer = ((np.abs(kx) < np.pi / b) & (np.abs(ky) < np.pi / b)).astype(float)
    else:
        raise ValueError(f"unknown window {window!r}; choose from {WINDOWS}")
    shift = np.exp(1j * (kx + ky) * (b - 1) / 2)  # f(x + c) ↔ f̂ e^{ikc}
    out = np.empty((nb, nb, 2))
    for c in range(2):
        filtered = np.fft.ifft2(np.fft.fft2(m[..., c]) * transfer * shift).real
        out[..., c] = filtered[::b, ::b]
    return out


def expand(facets: np.ndarray, b: int) -> np.ndarray:
    """Each facet's value repeated over its ``b × b`` pixels: (nb, nb, 2) → (nb b, nb b, 2)."""
    return np.repeat(np.repeat(facets, b, axis=0), b, axis=1)


# -- exact lattice histograms --------------------------------------------------------------


def lattice_masses(samples: np.ndarray, radius: int, weights=None) -> np.ndarray:
    """Probability masses of integer lattice samples (…, 2) on ``[−radius, radius]²``.

    Rows are the y component, columns x. Raises when a sample lies outside.
    """
    s = samples.reshape(-1, 2)
    if np.abs(s).max(initial=0) > radius:
        raise ValueError("lattice radius too small for the samples")
    side = 2 * radius + 1
    idx = (s[:, 1] + radius) * side + (s[:, 0] + radius)
    w = None if weights is None else np.ravel(weights)
    counts = np.bincount(idx, weights=w, minlength=side * side).reshape(side, side)
    return counts / counts.sum()


def convolve_masses(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Discrete convolution of two centred lattice mass arrays of equal odd side, same side."""
    side = p.shape[0]
    full = 2 * side - 1
    out = np.fft.irfft2(np.fft.rfft2(p, (full, full)) * np.fft.rfft2(q, (full, full)), s=(full, full))
    r = side // 2
    return np.maximum(out[r : r + side, r : r + side], 0.0)


def total_variation(p: np.ndarray, q: np.ndarray) -> float:
    """``½ Σ |p − q|`` of two mass arrays: 0 for equal distributions, 1 for disjoint ones."""
    return 0.5 * float(np.abs(p - q).sum())


# -- lobes on slope grids ------------------------------------------------------------------


def node_grid(extent: float, bins: int) -> np.ndarray:
    """Nodes ``u`` (bins, bins, 2) over ``[−extent, extent]²`` (rows u_y, columns u_x)."""
    x = np.linspace(-extent, extent, bins)
    return np.stack(np.meshgrid(x, x, indexing="xy"), axis=-1)


def tabulated_moments(values: np.ndarray, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean (2,) and covariance (2, 2) of node masses on the grid of :func:`node_grid`."""
    u = node_grid(extent, values.shape[0]).reshape(-1, 2)
    p = np.ravel(values) / np.sum(values)
    mean = p @ u
    d = u - mean
    return mean, (d * p[:, None]).T @ d


def l1_error(predicted: np.ndarray, measured: np.ndarray, extent: float) -> float:
    """``∫ |g_pred − g_meas| d²u`` on the nodes of a grid (densities per slope area); in [0, 2]."""
    h = 2 * extent / (measured.shape[0] - 1)
    return float(np.abs(predicted - measured).sum() * h * h)


def gaussian_density(u: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Bivariate normal density at ``u`` (…, 2)."""
    d = u - mean
    inv = np.linalg.inv(cov)
    q = np.einsum("...i,ij,...j->...", d, inv, d)
    return np.exp(-0.5 * q) / (2 * np.pi * np.sqrt(np.linalg.det(cov)))


def second_moment_covariance(lobe_cov, s_from_cov, s_to_cov, floor: float) -> tuple[np.ndarray, bool]:
    """LEAN/Toksvig-style filtering: slope covariances add, ``Σ_g(μ) = Σ_g(μ0) + Σ_s(μ0) − Σ_s(μ)``.

    Going finer the sum may lose positive definiteness; eigenvalues are then clipped at
    ``floor²`` and the second return value says so.
    """
    cov = np.asarray(lobe_cov) + np.asarray(s_from_cov) - np.asarray(s_to_cov)
    cov = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(cov)
    clipped = bool(np.any(w < floor**2))
    return (v * np.maximum(w, floor**2)) @ v.T, clipped


# -- the evolution with a regularisation the library accepts -------------------------------------

LAMBDA_STEP = 3.0
LAMBDA_TRIES = 8


def evolve_accepted(lobe, s_from, s_to, evaluate, *, regularisation: float, size: int):
    """``evaluate(brdfscale.evolve(lobe, s_from, s_to, "grid", size=size, regularisation=λ))``
    with the smallest λ of the ladder ``λ0, 3λ0, 9λ0, …`` (``1e-3, 3e-3, …`` after λ0 = 0)
    for which the library finds a non-negative lobe.

    Tabulated statistics are noisy, so the quotient ``G S_from / S_to`` can exceed 1 in
    modulus and :func:`brdfscale.evolve` refuses it (:class:`brdfscale.NoBRDFAtScaleError`,
    raised when the lobe is evaluated). Returns ``(evaluate(...), λ, refusals)``.
    """
    lam = float(regularisation)
    for attempt in range(LAMBDA_TRIES):
        try:
            evolved = bs.evolve(lobe, s_from, s_to, method="grid", size=size, regularisation=lam)
            return evaluate(evolved), lam, attempt
        except bs.NoBRDFAtScaleError:
            lam = LAMBDA_STEP * lam if lam > 0 else 1e-3
    raise bs.NoBRDFAtScaleError(f"no non-negative lobe up to λ = {lam / LAMBDA_STEP:g}")
