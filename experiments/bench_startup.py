"""Start-up time of the command line and of the imports, against a baseline revision (issue 17).

Measures, in fresh interpreters, the wall time of ``brdfscale --help``, ``brdfscale info FILE``
(a two-part measurement file), ``import brdfscale`` and ``import fitting`` for the working
tree and for a baseline revision exported from git (``--baseline-rev``, default 7d40106: the
last commit before the lazy imports), the two alternated run by run (:func:`interleaved_times`)
so both see the same machine. Each child starts in its own tree (``python -m`` and ``-c`` put
the working directory first on the import path), so each imports its own brdfscale. Writes
experiments/results/bench_startup.json; docs/benchmarks.md shows it.

Run from the checkout: ``python -m experiments.bench_startup [--repeat N] [--baseline-rev REV]``.
"""

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from experiments._bench import interleaved_times, machine, median, write_json


ROOT = Path(__file__).resolve().parent.parent

CASES = {
    "brdfscale --help": ["-m", "brdfscale", "--help"],
    "brdfscale info FILE": ["-m", "brdfscale", "info", "{file}"],
    "import brdfscale": ["-c", "import brdfscale"],
    # a tree exported from git is not installed: its fitting/ folder (installed as brdfscale.fitting)
    # is imported from the tree's root under the folder's name, the same code in both trees
    "import fitting": ["-c", "import fitting"],
}


def _export(rev: str, into: Path) -> Path:
    tree = into / "baseline"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def _measurement_file(into: Path) -> Path:
    import numpy as np

    from brdfscale import exr, LobeImage, MeasurementSet

    path = into / "m.exr"
    images = tuple(
        LobeImage(
            mu=mu, incident=np.array([0.0, 0.0, 1.0]), extent=0.5, values=np.ones((16, 16)), sigma=np.ones((16, 16))
        )
        for mu in (1.0, 2.0)
    )
    exr.write_measurements(path, MeasurementSet(images))
    return path


def _runner(tree: Path, argv: list[str]):
    def run():
        out = subprocess.run([sys.executable, *argv], cwd=tree, capture_output=True, text=True)
        if out.returncode != 0:
            raise RuntimeError(f"{argv} in {tree} failed: {out.stderr[-500:]}")

    return run


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench_startup", description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=9, help="runs of each case in each tree (default 9)")
    parser.add_argument("--baseline-rev", default="7d40106", help="git revision to compare with (default 7d40106)")
    args = parser.parse_args(argv)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        baseline = _export(args.baseline_rev, tmp)
        file = _measurement_file(tmp)
        fns = {}
        for case, template in CASES.items():
            command = [a.format(file=file) for a in template]
            fns[(case, "current")] = _runner(ROOT, command)
            fns[(case, "baseline")] = _runner(baseline, command)
        times = interleaved_times(fns, repeat=args.repeat)
    rows = []
    for case in CASES:
        now, before = times[(case, "current")], times[(case, "baseline")]
        rows.append(
            {
                "case": case,
                "baseline_median_s": median(before),
                "current_median_s": median(now),
                "baseline_min_s": before[0],
                "current_min_s": now[0],
                "speedup_median": median(before) / median(now),
            }
        )
        print(
            f"{case:22s} baseline {median(before):6.3f} s   now {median(now):6.3f} s   "
            f"({median(before) / median(now):.1f}× faster)"
        )
    path = write_json(
        "bench_startup",
        {
            "benchmark": "bench_startup",
            "machine": machine(),
            "repeat": args.repeat,
            "baseline_rev": args.baseline_rev,
            "load_average_at_start": load,
            "cases": rows,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
