"""Convergence diagnostics of MCMC draws: rank-normalised split R̂, bulk and tail ESS, MCSE, and emcee's τ.

The figures are those of ``arviz.summary`` (ArviZ 0.23, ``kind="diagnostics"``, the default
``stat_focus="mean"``), computed here in NumPy so that a run's status needs no ArviZ (an
optional extra; tests/test_samplers.py checks equality with ArviZ on a stored chain). For
draws ``x`` of shape (chains, draws), following Vehtari, Gelman, Simpson, Carpenter and
Bürkner (2021), *Rank-normalization, folding, and localization: an improved R̂*, Bayesian
Analysis 16, 667:

* split chains: each chain's first and last ``⌊n/2⌋`` draws become two chains (the middle
  draw of an odd n is dropped);
* z-scale: ranks over all draws (ties averaged), ``Φ⁻¹((rank − 3/8)/(N + 1/4))``;
* ``ess`` of an array: Geyer's initial monotone sequence estimator on the FFT
  autocovariances averaged over chains, ``N/τ̂`` with ``τ̂ ≥ 1/log10 N``;
* ``ess_bulk`` = ess(z-scale(split(x))); ``ess_tail`` = min over q ∈ {0.05, 0.95} of
  ess(split(x ≤ quantile_q(x))) (R's type-7 quantile);
* ``r_hat`` = max(R̂(z-scale(split(x))), R̂(z-scale(split(|x − median x|)))), R̂ the
  classic potential scale reduction; NaN with fewer than 2 chains or 4 draws;
* ``mcse_mean`` = √(var(x)/ess(split(x))), ``mcse_sd`` from the ESS of the squared
  deviations (ArviZ's formula).

Also emcee's integrated autocorrelation time τ (the ensemble estimator the report has used
since its first version: autocorrelation averaged over walkers) and the burn-in rule of the
emcee runs (2 τ_max, at most half the chain).
"""

import logging
import math

import numpy as np
from scipy import fft, stats


__all__ = [
    "ESS_BULK_LIMIT",
    "R_HAT_LIMIT",
    "STATISTICS",
    "ess",
    "ess_bulk",
    "ess_tail",
    "integrated_time",
    "mcse_mean",
    "mcse_sd",
    "pareto_k",
    "r_hat",
    "summary_row",
]

R_HAT_LIMIT = 1.01
"""A run whose R̂ exceeds this on a determined quantity has not converged (Vehtari et al. 2021)."""
ESS_BULK_LIMIT = 400
"""A run whose bulk ESS is below this on a determined quantity is too short to trust its R̂ and intervals."""
STATISTICS = ("mean", "sd", "mcse_mean", "mcse_sd", "ess_bulk", "ess_tail", "r_hat")


def _two_d(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x[None, :] if x.ndim == 1 else x


def _valid(x, min_chains: int = 1) -> bool:
    return not np.isnan(x).any() and x.shape[0] >= min_chains and x.shape[1] >= 4


def _split(x) -> np.ndarray:
    half = x.shape[1] // 2
    return np.vstack((x[:, :half], x[:, x.shape[1] - half :]))


def _z_scale(x) -> np.ndarray:
    rank = stats.rankdata(x, method="average").reshape(x.shape)
    return stats.norm.ppf((rank - 3 / 8) / (x.size - 2 * (3 / 8) + 1))


def _autocov(x) -> np.ndarray:
    n = x.shape[1]
    m = fft.next_fast_len(2 * n)
    c = x - x.mean(axis=1, keepdims=True)
    f = np.fft.rfft(c, n=m, axis=1)
    f *= np.conjugate(f)
    return np.fft.irfft(f, n=m, axis=1)[:, :n] / n


def ess(x) -> float:
    """The effective sample size of a (chains, draws) array (no splitting, no ranks)."""
    x = _two_d(x)
    if np.isnan(x).any():
        return np.nan
    if np.max(x) - np.min(x) < np.finfo(float).resolution:
        return float(x.size)
    n_chain, n_draw = x.shape
    acov = _autocov(x)
    mean_var = np.mean(acov[:, 0]) * n_draw / (n_draw - 1.0)
    var_plus = mean_var * (n_draw - 1.0) / n_draw
    if n_chain > 1:
        var_plus += np.var(x.mean(axis=1), ddof=1)
    rho = np.zeros(n_draw)
    rho_even, rho_odd = 1.0, 1.0 - (mean_var - np.mean(acov[:, 1])) / var_plus
    rho[0], rho[1] = rho_even, rho_odd
    t = 1
    while t < n_draw - 3 and rho_even + rho_odd > 0.0:  # Geyer's initial positive sequence
        rho_even = 1.0 - (mean_var - np.mean(acov[:, t + 1])) / var_plus
        rho_odd = 1.0 - (mean_var - np.mean(acov[:, t + 2])) / var_plus
        if rho_even + rho_odd >= 0:
            rho[t + 1], rho[t + 2] = rho_even, rho_odd
        t += 2
    max_t = t - 2
    if rho_even > 0:
        rho[max_t + 1] = rho_even
    t = 1
    while t <= max_t - 2:  # Geyer's initial monotone sequence
        if rho[t + 1] + rho[t + 2] > rho[t - 1] + rho[t]:
            rho[t + 1] = rho[t + 2] = (rho[t - 1] + rho[t]) / 2.0
        t += 2
    total = n_chain * n_draw
    tau = -1.0 + 2.0 * np.sum(rho[: max_t + 1]) + np.sum(rho[max_t + 1 : max_t + 2])
    tau = max(tau, 1 / np.log10(total))
    return np.nan if np.isnan(rho).any() else float(total / tau)


def _rhat(x) -> float:
    n = x.shape[1]
    between = n * np.var(x.mean(axis=1), ddof=1)
    within = np.mean(np.var(x, axis=1, ddof=1))
    return float(np.sqrt((between / within + n - 1) / n))


def ess_bulk(x) -> float:
    x = _two_d(x)
    return ess(_z_scale(_split(x))) if _valid(x) else np.nan


def ess_tail(x) -> float:
    x = _two_d(x)
    if not _valid(x):
        return np.nan
    low, high = np.quantile(x, [0.05, 0.95])
    return min(ess(_split(x <= low)), ess(_split(x <= high)))


def r_hat(x) -> float:
    x = _two_d(x)
    if not _valid(x, min_chains=2):
        return np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        bulk = _rhat(_z_scale(_split(x)))
        tail = _rhat(_z_scale(_split(np.abs(x - np.median(x)))))
    return max(bulk, tail)


def mcse_mean(x) -> float:
    x = _two_d(x)
    if not _valid(x):
        return np.nan
    c2 = (x - x.mean()) ** 2
    return float(np.sqrt(c2.sum() / (c2.size - 1) / ess(_split(x))))


def mcse_sd(x) -> float:
    x = _two_d(x)
    if not _valid(x):
        return np.nan
    c2 = (x - x.mean()) ** 2
    evar = c2.sum() / c2.size
    varvar = ((c2**2).mean() - evar**2) / ess(_split(c2))
    return float(np.sqrt(varvar / evar / 4))


def summary_row(x) -> dict:
    """``mean``, ``sd`` (ddof 1, as ArviZ) and the diagnostics of ``STATISTICS`` for (chains, draws) draws."""
    x = _two_d(x)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "mean": float(np.mean(x)),
            "sd": float(np.std(x, ddof=1)) if x.size > 1 else np.nan,
            "mcse_mean": mcse_mean(x),
            "mcse_sd": mcse_sd(x),
            "ess_bulk": ess_bulk(x),
            "ess_tail": ess_tail(x),
            "r_hat": r_hat(x),
        }


def integrated_time(chain) -> np.ndarray:
    """emcee's integrated autocorrelation time of a (steps, walkers, d) chain, per coordinate
    (NaN where no walker moved; emcee's short-chain warning is silenced: the caller reports it)."""
    import emcee

    logger = logging.getLogger("emcee.autocorr")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with np.errstate(invalid="ignore", divide="ignore"):
            return emcee.autocorr.integrated_time(chain, quiet=True)
    finally:
        logger.setLevel(level)


def pareto_k(log_weights) -> float:
    """The Pareto k̂ of importance weights given by their logarithms (any common offset): the shape of a generalised
    Pareto distribution fitted to the largest weights — how heavy their right tail is — as in Pareto smoothed
    importance sampling (Vehtari, Simpson, Gelman, Yao & Gabry 2024, *Pareto smoothed importance sampling*, JMLR
    25(72); ArviZ's ``psislw``, whose k̂ this equals: tests/test_samplers.py).

    The tail is the M = ⌈min(S/5, 3√S)⌉ largest of S weights, above the next largest; the shape comes from Zhang
    and Stephens' (2009) empirical-Bayes fit of the exceedances, shrunk towards 0.5 by a prior worth 10 draws.
    k̂ < 0.5: the weights have a finite variance; 0.5–0.7: finite mean, the estimate slow to converge; above 0.7
    the importance sampler — and an independence sampler with that proposal — is not to be trusted. ``inf`` when
    fewer than 5 weights exceed the tail's threshold (a few weights dominate, or too few draws). Non-finite log
    weights count as weight 0.
    """
    x = np.asarray(log_weights, dtype=float).ravel()
    x = np.where(np.isfinite(x), x, -np.inf)
    if x.size < 5 or not np.isfinite(np.max(x)):
        return math.inf
    x = x - np.max(x)
    order = np.sort(x)
    cutoff = max(order[-int(np.ceil(min(0.2 * x.size, 3 * np.sqrt(x.size)))) - 1], np.log(np.finfo(float).tiny))
    tail = np.sort(x[x > cutoff])
    if tail.size <= 4:
        return math.inf
    exceed = np.exp(tail) - np.exp(cutoff)
    n = exceed.size
    m_est = 30 + int(n**0.5)
    b = 1 - np.sqrt(m_est / (np.arange(1, m_est + 1, dtype=float) - 0.5))
    b = b / (3 * exceed[int(n / 4 + 0.5) - 1]) + 1 / exceed[-1]
    k = np.log1p(-b[:, None] * exceed).mean(axis=1)
    length = n * (np.log(-(b / k)) - k - 1)
    weights = 1 / np.exp(length - length[:, None]).sum(axis=1)
    keep = weights >= 10 * np.finfo(float).eps
    b, weights = b[keep], weights[keep] / weights[keep].sum()
    k_post = np.log1p(-np.sum(b * weights) * exceed).mean()
    return float((n * k_post + 10 * 0.5) / (n + 10))
