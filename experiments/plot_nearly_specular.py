"""Nearly-specular lobes (seed §6, docs/conventions.md §4) as instruments of two angular resolutions see them.

For n = 0…3 the statistic ``s = δ + c_n h_n`` (cut-off x0) next to a pure specular lobe (δ)
and a Beckmann lobe (α = x0/2), all of unit energy (∫ g d²u = 1: plus-distributions carry no
mass), each convolved with a Gaussian instrument kernel of per-axis width σ = x0/30 (fine)
and σ = x0/3 (coarse). ``c_n = (−1)ⁿ 0.3 (n+1)/ln(x0/σ_fine)^{n+1}`` makes the off-centre
density positive and removes about 30 % of the δ's weight at the fine resolution, so both
views are non-negative (checked by brdfscale.plus.observe).

    python -m experiments.plot_nearly_specular   # writes results/nearly_specular/lobes.png + .json
"""

import argparse
import math

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from brdfscale import evolve, lobes, plus, stats  # noqa: E402
from experiments._studies import save_figure, study_dir, write_results  # noqa: E402


X0 = 0.05
SIGMAS = {"fine": X0 / 30, "coarse": X0 / 3}
ORDERS = range(4)


def strength(n: int) -> float:
    return (-1) ** n * 0.3 * (n + 1) / math.log(X0 / SIGMAS["fine"]) ** (n + 1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    out = study_dir("nearly_specular", args.out)

    r = np.linspace(0.0, 2.0 * X0, 401)
    u = jnp.asarray(np.stack([r, np.zeros_like(r)], axis=-1))
    curves, minima = {}, {}
    for name, sigma in SIGMAS.items():
        kernel = stats.Gaussian(sigma=sigma)
        curves[name] = {
            "specular δ": np.asarray(kernel.density(u)),
            "Beckmann α = x0/2": np.asarray(evolve(lobes.Beckmann(X0 / 2), kernel, stats.Delta()).density(u)),
        }
        for n in ORDERS:
            c = np.zeros(n + 1)
            c[n] = strength(n)
            seen = plus.observe(plus.NearlySpecular(1.0, c, X0), kernel)  # raises if negative
            curves[name][f"δ + c_{n} h_{n}"] = np.asarray(seen.density(u))
            minima[f"{name}/n={n}"] = float(seen.minimum()[0])

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, (name, sigma) in zip(axes, SIGMAS.items()):
        for label, values in curves[name].items():
            style = (
                {"color": "k", "lw": 2}
                if label.startswith("specular")
                else ({"color": "0.5", "ls": "--"} if label.startswith("Beckmann") else {})
            )
            ax.semilogy(r / X0, np.maximum(values, 1e-3), label=label, **style)
        ax.set_title(f"{name} instrument: Gaussian σ = x0/{X0 / sigma:.0f}")
        ax.set_xlabel("|u| / x0 (half-vector slope offset)")
        ax.set_ylim(1e-1, None)
        ax.axvline(1.0, color="0.8", lw=0.8)
    axes[0].set_ylabel("lobe g(u) per unit slope area (unit energy)")
    axes[1].legend(fontsize=8)
    fig.suptitle(f"Nearly-specular lobes δ + c_n h_n (x0 = {X0}), c_n = (−1)ⁿ·0.3(n+1)/ln(x0/σ_fine)^(n+1)")
    png = save_figure(fig, out / "lobes.png")
    write_results(
        out,
        "lobes",
        {
            "x0": X0,
            "sigmas": SIGMAS,
            "strengths": {f"c_{n}": strength(n) for n in ORDERS},
            "minimum_seen": minima,
            "peak": {name: {k: float(v.max()) for k, v in c.items()} for name, c in curves.items()},
        },
    )
    print(png)


if __name__ == "__main__":
    main()
