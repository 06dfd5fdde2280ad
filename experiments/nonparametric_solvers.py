"""Why the anisotropic non-parametric model's fit is slow (issue 31 item 8: ≤ 3 min cold, unmet): its
least-squares problem on experiments/bench_anisotropic.py's synthetic set (8 scales, 65² px), three ways.

1. ``fitting.fit(model, data, starts=1, solver="lm_normal")`` as the command ran it per start before the
   model preferred ``gauss_newton_edm`` (Levenberg–Marquardt with normal-equation steps, ``max_steps`` 256): wall
   time, result, χ².
2. The Gauss–Newton Hessian ``JᵀJ`` at the model's start: its smallest eigenvalues against its largest and the
   parameters its smallest eigenvectors load on (the directions the data do not determine).
3. Gauss–Newton with a backtracking line search (Armijo, step halved until χ² falls by 1e-4 of the predicted
   decrease), its step from the eigen-decomposition of ``JᵀJ`` with eigenvalues below ``rcond`` × the largest left
   out, stopped when the expected distance to the minimum ``EDM = ½ gᵀ(JᵀJ)⁺g`` (g = Jᵀr: the decrease of ½χ² the
   Newton step predicts) falls below 1e-3 or after
   ``--iterations``: χ², EDM, step length and time per iteration, for ``rcond`` 1e-9 and 1e-12 — not a solver of the
   library, a measurement of how far the problem is from the optimum after a given amount of work.
4. ``fitting.fit(model, data)`` with its defaults now (``solver="auto"``: the model's ``gauss_newton_edm``, the
   iteration of 3 in the library, its directions left out by their curvature against the noise rather than by
   ``rcond`` — fitting._gauss_newton; ``starts="auto"``: 1), twice — the first call compiles: wall time, result,
   steps (accepted and rejected trial points), χ².

Model: ``fitting.AnisotropicNonParametricModel(data, base_nodes=13, n_knots=8)`` — the command's defaults
(``brdfscale.choices.MODEL``), regularisation 3, no odd part (``odd_harmonics=0``, pinned: the odd part was added
to the model after this study).

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.nonparametric_solvers [--iterations 80] [--library-only]
Writes experiments/results/nonparametric_solvers.json; ``--library-only`` runs 4 alone and replaces its rows in the
existing JSON (each row with its own code commit and date; 1–3 keep theirs, the file's ``code_commit``).
"""

import argparse
import json
import tempfile
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import brdfscale as bs
from brdfscale import fitting
from brdfscale.choices import MODEL
from experiments._bench import code_commit, machine, RESULTS, write_json
from experiments.bench_anisotropic import synthetic_set


EDM_STOP = 1e-3


def gauss_newton(problem, theta, *, rcond: float, iterations: int) -> list[dict]:
    """The line-searched Gauss–Newton iterations of the module docstring (3): one record per iteration."""
    residuals = eqx.filter_jit(lambda t: problem.residuals(t))
    jacobian = eqx.filter_jit(lambda t: jax.jacfwd(problem.residuals)(t))
    r = residuals(theta)
    chi2 = float(r @ r)
    jacobian(theta).block_until_ready()  # compiled before the clock starts
    started, rows = time.perf_counter(), []
    for k in range(iterations):
        J = jacobian(theta)
        g = J.T @ r
        w, V = jnp.linalg.eigh(J.T @ J)
        keep = w > rcond * w[-1]
        step = -(V @ jnp.where(keep, (V.T @ g) / jnp.where(keep, w, 1.0), 0.0))
        edm = -0.5 * float(g @ step)
        alpha = 1.0
        while True:
            trial = residuals(theta + alpha * step)
            value = float(trial @ trial)
            if np.isfinite(value) and value < chi2 - 1e-4 * alpha * 2 * edm:
                break
            alpha *= 0.5
            if alpha < 1e-6:
                break
        theta, r, chi2 = theta + alpha * step, trial, value
        rows.append(
            {"iteration": k + 1, "chi2": chi2, "edm": edm, "alpha": alpha, "seconds": time.perf_counter() - started}
        )
        if edm < EDM_STOP:
            break
    return rows


def library_default(model, data) -> list[dict]:
    """4 of the module docstring: ``fitting.fit(model, data)`` with its defaults, twice (the first call compiles)."""
    rows = []
    for call in ("first (compiles)", "second"):
        started = time.perf_counter()
        result = fitting.fit(model, data)
        rows.append(
            {
                "call": call,
                "seconds": time.perf_counter() - started,
                "solver": result.solver,
                "starts": len(result.starts),
                "status": result.status,
                "chi2": float(result.chi2),
                "steps": result.starts[0].get("steps"),
                "code_commit": code_commit(),
                "date_utc": machine()["date_utc"],
            }
        )
        print("library default:", rows[-1], flush=True)
    return rows


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=80)
    parser.add_argument("--out", default=None, help="output folder (default experiments/results)")
    parser.add_argument("--library-only", action="store_true", help="rerun 4 alone, into the existing JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.exr"
        described = synthetic_set(path)
        data = fitting.Dataset.from_measurements(bs.exr.read_measurements(str(path)))
    model = fitting.AnisotropicNonParametricModel(
        data, base_nodes=MODEL.base_nodes, n_knots=MODEL.knots, odd_harmonics=0
    )
    if args.library_only:
        with open(Path(args.out or RESULTS) / "nonparametric_solvers.json", encoding="utf-8") as f:
            payload = json.load(f)
        payload["library_default"] = library_default(model, data)
        write_json("nonparametric_solvers", payload, args.out)
        return payload
    problem = fitting.Problem(model, data)
    theta0 = jnp.asarray(model.initial(data))
    payload = {
        "machine": machine(),
        "code_commit": code_commit(),
        "command": "python -m experiments.nonparametric_solvers",
        "set": described,
        "parameters": len(model.names),
        "rows": int(np.asarray(problem.residuals(theta0)).size),
        "chi2_start": float(problem.chi2(theta0)),
    }

    started = time.perf_counter()
    result = fitting.fit(model, data, starts=1, solver="lm_normal")
    payload["fit"] = {
        "seconds": time.perf_counter() - started,
        "solver": result.solver,
        "status": result.status,
        "chi2": float(result.chi2),
        "steps": result.starts[0].get("steps") if result.starts else None,
    }
    print("fit:", payload["fit"], flush=True)

    J = np.asarray(jax.jacfwd(problem.residuals)(theta0))
    w, V = np.linalg.eigh(J.T @ J)
    names = model.names
    payload["hessian_at_start"] = {
        "largest": float(w[-1]),
        "smallest": [float(x) for x in w[:8]],
        "smallest_directions": [[names[j] for j in np.argsort(-np.abs(V[:, i]))[:4]] for i in range(4)],
    }

    payload["gauss_newton"] = {}
    for rcond in (1e-9, 1e-12):
        rows = gauss_newton(problem, theta0, rcond=rcond, iterations=args.iterations)
        payload["gauss_newton"][f"{rcond:g}"] = {"rcond": rcond, "iterations": rows}
        print(f"Gauss–Newton rcond {rcond:g}:", rows[-1], flush=True)
    payload["library_default"] = library_default(model, data)
    write_json("nonparametric_solvers", payload, args.out)
    return payload


if __name__ == "__main__":
    main()
