"""Shared helpers of the benchmark scripts: timing, machine description, atomic JSON output."""

import json
import os
import platform
import subprocess
import sys
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path


RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """The machine and library versions a benchmark ran on."""
    import jax

    versions = {}
    for pkg in ("brdfscale", "jax", "jaxlib", "equinox", "optimistix", "numpy", "scipy", "emcee", "OpenEXR", "s2fft"):
        try:
            versions[pkg] = version(pkg)
        except PackageNotFoundError:
            versions[pkg] = None
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "versions": versions,
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


TRACEBACK = "Traceback (most recent call last)"
"""What Python prints before a traceback: a command that lets one reach the terminal has a defect."""


def brdfscale_command(*args: str, env: dict | None = None, timeout: float = 900) -> dict:
    """``brdfscale ARGS`` in a fresh process (``python -m brdfscale``, matplotlib's Agg backend): its exit status
    (None past ``timeout`` seconds), its last non-empty line (stderr's, else stdout's), whether a Python traceback
    reached the terminal, how many non-empty lines it wrote on stderr, and the wall time."""
    t0 = time.perf_counter()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "brdfscale", *args],
            capture_output=True,
            text=True,
            env={**os.environ, "MPLBACKEND": "Agg", **(env or {})},
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return {
            "exit": None,
            "line": f"timed out after {timeout:g} s",
            "traceback": False,
            "stderr_lines": 0,
            "wall_s": round(time.perf_counter() - t0, 2),
        }
    lines = [line for line in (done.stderr.strip().splitlines() or done.stdout.strip().splitlines()) if line.strip()]
    return {
        "exit": done.returncode,
        "line": lines[-1] if lines else "",
        "traceback": TRACEBACK in done.stderr or TRACEBACK in done.stdout,
        "stderr_lines": sum(1 for line in done.stderr.splitlines() if line.strip()),
        "wall_s": round(time.perf_counter() - t0, 2),
    }


def code_commit() -> str | None:
    """The commit of the code benchmarked: ``git rev-parse HEAD`` of this checkout, or the ``COMMIT`` file of
    a ``git archive`` snapshot (a benchmark run on a frozen copy while the working tree changes)."""
    root = Path(__file__).resolve().parent.parent
    if (root / "COMMIT").exists():
        return (root / "COMMIT").read_text().strip()
    done = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True)
    return done.stdout.strip() or None


def best_time(fn, *, repeat: int = 5, number: int = 1, budget: float = 0.0) -> float:
    """Best wall time of ``number`` calls of ``fn`` over ``repeat`` rounds (seconds per call),
    and more rounds while less than ``budget`` seconds have been spent (so that sub-millisecond
    calls get enough rounds for their best to be representative).

    ``fn`` must block until its result is ready (call ``block_until_ready`` inside)."""
    fn()  # warm-up (compilation)
    best, rounds, started = float("inf"), 0, time.perf_counter()
    while rounds < repeat or time.perf_counter() - started < budget:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
        rounds += 1
    return best


def rotated(names, k: int) -> list:
    """``names`` (any iterable) rotated left by ``k``: round ``k``'s order, so that no
    candidate always runs in the same position."""
    names = list(names)
    return names[k % len(names) :] + names[: k % len(names)]


def interleaved_times(fns: dict, *, repeat: int = 15) -> dict:
    """Wall times (seconds, sorted) of each of ``fns`` (name → blocking callable) over
    ``repeat`` rounds, the calls alternated within each round so that every candidate sees
    the same machine conditions (on a shared machine, back-to-back phases can differ by tens
    of per cent); the order rotates from round to round, so no candidate always follows the
    same one."""
    for fn in fns.values():
        fn()  # warm-up (compilation)
    times = {name: [] for name in fns}
    for round_ in range(repeat):
        for name in rotated(fns, round_):
            fn = fns[name]
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: sorted(t) for name, t in times.items()}


def best_times_interleaved(fns: dict, *, repeat: int = 15) -> dict:
    """Best (minimum) wall time of each of ``fns`` by :func:`interleaved_times`."""
    return {name: t[0] for name, t in interleaved_times(fns, repeat=repeat).items()}


def median(sorted_times: list) -> float:
    n = len(sorted_times)
    return 0.5 * (sorted_times[(n - 1) // 2] + sorted_times[n // 2])


def write_json(name: str, payload: dict, folder: str | Path | None = None) -> Path:
    """Write ``<folder>/<name>.json`` atomically (temporary file + rename); ``folder`` defaults to ``results/``."""
    from brdfscale import files as _files

    folder = RESULTS if folder is None else Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.json"

    _files.write_text(path, json.dumps(payload, indent=2, sort_keys=False) + "\n", overwrite=True)
    return path


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table. A ``|`` inside a cell (``|M| ≤ 27``) is escaped, so that it does not end
    the cell; a row with more or fewer cells than the header is refused."""

    def line(cells):
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    for r in rows:
        if len(r) != len(header):
            raise ValueError(f"a table row has {len(r)} cells, its header {len(header)}: {r!r}")
    lines = [line(header), "|" + "---|" * len(header)]
    lines += [line(r) for r in rows]
    return "\n".join(lines)
