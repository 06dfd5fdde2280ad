"""Which model the data prefer: information criteria of fits to the same data (:func:`compare`).

With Gaussian noise of known σ the log-likelihood at the optimum is ``log L̂ = −χ²/2 + c``, the
constant ``c`` the same for every model fitted to the same pixels, so (Akaike 1974; Schwarz 1978)

    AIC = χ² + 2 p,        BIC = χ² + p ln n,

with ``p`` the number of fitted coordinates θ and ``n`` the number of data rows (valid pixels,
plus a joint fit's topography rows). The smaller value is preferred; a difference above about 10
is strong (Burnham & Anderson 2002, for AIC; Kass & Raftery 1995, for BIC). ``brdfscale fit
--compare`` fits its candidate models and reports the one of smallest BIC (docs/fitting.md).
"""

import math
from collections.abc import Mapping

from brdfscale import InvalidInputError
from brdfscale.show import Shown, Table

from ._result import FitResult


__all__ = ["compare", "Comparison"]


class Comparison(Shown):
    """The table of :func:`compare`: ``rows`` (a dict per model, ascending BIC) and ``preferred``
    (the model of smallest BIC, and of smallest AIC)."""

    def __init__(self, rows: list[dict]):
        self.rows = rows
        self.preferred = {"bic": rows[0]["model"], "aic": min(rows, key=lambda r: r["aic"])["model"]}

    def _show_items(self):
        return [("preferred (BIC)", self.preferred["bic"]), ("preferred (AIC)", self.preferred["aic"])]

    def _show_tables(self):
        columns = ("model", "chi2", "parameters", "n", "aic", "bic", "delta_aic", "delta_bic")
        return [
            Table(
                "information criteria (AIC = χ² + 2p, BIC = χ² + p ln n; smaller is preferred)",
                columns,
                [tuple(r[c] for c in columns) for r in self.rows],
            )
        ]

    def lines(self) -> list[str]:
        """The table as text lines (the command prints them)."""
        width = max(14, *(len(r["model"]) for r in self.rows))
        out = [f"  {'model':{width}s} {'χ²':>12s} {'p':>4s} {'AIC':>12s} {'BIC':>12s} {'ΔBIC':>9s}"]
        for r in self.rows:
            out.append(
                f"  {r['model']:{width}s} {r['chi2']:12.2f} {r['parameters']:4d} {r['aic']:12.2f} "
                f"{r['bic']:12.2f} {r['delta_bic']:9.2f}"
            )
        out.append(f"  preferred: {self.preferred['bic']} (BIC), {self.preferred['aic']} (AIC)")
        return out

    def to_json(self) -> dict:
        return {"criterion": "AIC = chi2 + 2p, BIC = chi2 + p ln n", "rows": self.rows, "preferred": self.preferred}


def compare(results: Mapping[str, FitResult]) -> Comparison:
    """AIC and BIC of fits of several models to the same data (module docstring).

    Args:
        results: model name → its :class:`FitResult` (at least two).

    Raises:
        InvalidInputError: not a mapping of names to at least two FitResults, or results of
            different data (different numbers of data rows: their χ² are not comparable).
    """
    if not isinstance(results, Mapping) or len(results) < 2:
        raise InvalidInputError(
            f"compare needs a dict of at least two model names → FitResult; got {type(results).__name__}"
            f"{f' of {len(results)}' if isinstance(results, Mapping) else ''}."
        )
    for name, result in results.items():
        if not isinstance(result, FitResult):
            raise InvalidInputError(
                f"compare: results[{name!r}] must be a fitting.FitResult; got {type(result).__name__}."
            )
    sizes = {name: r.n_data for name, r in results.items()}
    if len(set(sizes.values())) > 1:
        raise InvalidInputError(
            f"compare: the fits have different numbers of data rows {sizes}; information criteria compare "
            "models fitted to the same data only."
        )
    rows = []
    for name, r in results.items():
        p, n = len(r.names), r.n_data
        rows.append(
            {
                "model": str(name),
                "chi2": r.chi2,
                "parameters": p,
                "n": n,
                "aic": r.chi2 + 2 * p,
                "bic": r.chi2 + p * math.log(n),
            }
        )
    rows.sort(key=lambda row: row["bic"])
    best_aic, best_bic = min(r["aic"] for r in rows), rows[0]["bic"]
    for row in rows:
        row["delta_aic"], row["delta_bic"] = row["aic"] - best_aic, row["bic"] - best_bic
    return Comparison(rows)
