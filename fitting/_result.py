"""The outcome of a fit: :class:`FitResult` (NumPy and Python values, ``to_json()`` for reports).

What it holds is computed by :mod:`fitting._analysis` (best start, Laplace analysis,
identifiability) and :mod:`fitting._derived` (quantities and ratios at θ̂ and the Laplace
draws). A value the data do not determine is ``None`` (JSON ``null``): the one representation
of "undetermined" in fitting, :mod:`brdfscale.laplace` and :mod:`brdfscale.plus`.
"""

import dataclasses

import numpy as np

from brdfscale.show import Shown, Table


__all__ = ["FitResult"]


@dataclasses.dataclass(repr=False)
class FitResult(Shown):
    """Outcome of :func:`fit` (all NumPy / Python values; ``to_json()`` for reports).

    ``status`` is ``"converged"`` when the best start's solver reported success, else the
    optimistix result name of the best start (e.g. ``"nonlinear_max_steps_reached"``), or
    ``"nonfinite"`` (θ̂, χ² or the Jacobian not finite) or ``"stopped_at_start"`` (the solve
    never left a start that is not stationary; fitting._solve).
    ``estimates``/``std``/``quantiles`` are keyed by quantity name; ``std`` and
    ``quantiles`` hold None for quantities that the data do not determine. ``at_bounds``
    lists coordinates that ended on the prior box's edge (there the residuals are flat in
    that coordinate, so it also shows up as undetermined).
    """

    names: tuple[str, ...]
    theta: np.ndarray
    covariance: np.ndarray
    chi2: float
    n_data: int
    status: str
    starts: list[dict]
    estimates: dict[str, float]
    std: dict[str, float | None]
    quantiles: dict[str, list[float] | None]
    eigenvalues: np.ndarray
    undetermined: list[dict]
    notes: list[str]
    solver: str
    at_bounds: list[str]
    eigenvectors: np.ndarray | None = None  # V of the Fisher matrix's eigen-decomposition, columns by eigenvalue
    ratios: dict = dataclasses.field(default_factory=dict)  # S(μ0)/S(μk) at reference |W| (ratio_frequencies)
    combinations: list = dataclasses.field(default_factory=list)  # determined Fisher eigen-directions: value ± std
    # ΔΣ(μ0, μk) = Σ(μ0) − Σ(μk) per coarser scale: {"mu0", "mu", "value" 2×2, "std" 2×2, "fixed" 2×2,
    # "note" only when the model fixes an entry} (fitting._derived.summarise_covariance_differences)
    covariance_differences: list = dataclasses.field(default_factory=list)
    # their joint covariance, 3(K − 1) rows: per coarser scale xx, xy, yy (fitting._derived.DIFFERENCE_COMPONENTS);
    # NaN rows and columns where an entry has no std (the correlations fitting.law_from_differences' χ² needs)
    differences_covariance: np.ndarray | None = None

    @property
    def dof(self) -> int:
        return max(self.n_data - len(self.names), 1)

    @property
    def determined(self) -> bool:
        return not self.undetermined

    def _estimate_text(self, name: str) -> str:
        std = self.std.get(name)
        return (
            f"{self.estimates[name]:.4g} ± {std:.2g}"
            if std is not None
            else f"{self.estimates[name]:.4g} (undetermined)"
        )

    def _show_items(self) -> list[tuple[str, object]]:
        items: list[tuple[str, object]] = [
            ("status", self.status),
            ("solver", self.solver),
            ("chi2/dof", f"{self.chi2:.4g}/{self.dof} = {self.chi2 / self.dof:.4g}"),
        ]
        items += [(name, self._estimate_text(name)) for name in self.estimates]
        if self.undetermined:
            items.append(("undetermined", "; ".join(u["combination"] for u in self.undetermined)))
        if self.at_bounds:
            items.append(("at_bounds", ", ".join(self.at_bounds)))
        return items

    def _show_tables(self):
        rows = []
        for name, value in self.estimates.items():
            q = self.quantiles.get(name) or (None, None, None)
            rows.append((name, value, self.std.get(name), *q))
        tables = [
            Table(
                "parameters (Laplace: estimate, standard deviation, 5/50/95 % quantiles; — where the data "
                "do not determine it)",
                ("quantity", "estimate", "std", "5 %", "50 %", "95 %"),
                rows,
            )
        ]
        if self.ratios:
            tables.append(
                Table(
                    "what the data determine: ratios S(W, μ0)/S(W, μk) (Laplace)",
                    ("ratio", "estimate", "std", "5 %", "95 %"),
                    [
                        (n, r["estimate"], r["std"], *((r["quantiles_5_50_95"] or [None] * 3)[::2]))
                        for n, r in self.ratios.items()
                    ],
                )
            )
        if self.covariance_differences:
            tables.append(
                Table(
                    "what the data determine: ΔΣ(μ0, μk) = Σ(μ0) − Σ(μk) (slope units², Laplace std)",
                    ("μ0", "μk", "xx", "xy", "yy"),
                    [
                        (d["mu0"], d["mu"], *(_entry(d, a, b) for a, b in ((0, 0), (0, 1), (1, 1))))
                        for d in self.covariance_differences
                    ],
                )
            )
        if self.combinations:
            tables.append(
                Table(
                    "determined combinations of θ (Fisher eigen-directions)",
                    ("combination", "value", "std"),
                    [(c["combination"], c["value"], c["std"]) for c in self.combinations],
                )
            )
        if self.undetermined:
            tables.append(
                Table(
                    "combinations the data do not determine",
                    ("combination", "Fisher eigenvalue", "std"),
                    [(u["combination"], u["fisher_eigenvalue"], u["std"]) for u in self.undetermined],
                )
            )
        return tables

    def plot(self, problem, **options):
        """Data, fit and whitened residuals per scale: :func:`brdfscale.plot.fit`, which is
        :func:`fitting.plot_fit` (``problem`` is the fit's, options as there); returns a
        ``matplotlib.figure.Figure``."""
        from brdfscale._figures import draw

        return draw("fit", problem, self, **options)

    def to_json(self) -> dict:
        return {
            "solver": self.solver,
            "status": self.status,
            "chi2": self.chi2,
            "n_data": self.n_data,
            "dof": self.dof,
            "reduced_chi2": self.chi2 / self.dof,
            "starts": self.starts,
            "at_prior_bounds": self.at_bounds,
            "theta_names": list(self.names),
            "theta": self.theta.tolist(),
            "estimates": self.estimates,
            "std": self.std,
            "quantiles_5_50_95": self.quantiles,
            "identifiability": {
                "fisher_eigenvalues": self.eigenvalues.tolist(),
                "determined_combinations": self.combinations,
                "undetermined_combinations": self.undetermined,
                "notes": self.notes,
            },
            "ratios": self.ratios,
            "covariance_differences": self.covariance_differences,
            "differences_covariance": _nan_as_none(self.differences_covariance),
        }


def _nan_as_none(matrix: np.ndarray | None) -> list | None:
    """A matrix as nested lists, None (JSON null) where an entry is not finite."""
    if matrix is None:
        return None
    return [[float(x) if np.isfinite(x) else None for x in row] for row in np.asarray(matrix, float)]


def _entry(difference: dict, a: int, b: int) -> str:
    """``value ± std`` of one entry of a ΔΣ record (``undetermined`` where its std is None;
    ``fixed by the isotropic model`` where the model sets it: fitting._derived.is_isotropic)."""
    value, std = difference["value"][a][b], difference["std"][a][b]
    if (difference.get("fixed") or [[False] * 2] * 2)[a][b]:
        return f"{value:.4g} (fixed by the isotropic model)"
    if value is None:
        return "undetermined"
    return f"{value:.4g} ± {std:.2g}" if std is not None else f"{value:.4g} (undetermined)"
