"""Benchmark: reading, detrending and the facet statistics at eight scales of measured surfaces (issue 18).

The issue's target: a 1000 × 1000 measurement read, detrended and its statistics measured at
8 scales in under 10 s on 2 cores.

Cases:

* every real instrument file of tests/data/topographies (AFM, interferometer, confocal,
  profilometer; 256 × 256 to 768 × 576 pixels; two of them with unmeasured pixels);
* ``x3p-1000``: a 1000 × 1000 measurement. No real file of that size is in the repository,
  so its heights are synthetic — a fractal (ABC) random surface, 1000 × 1000 pixels cut from
  a 1024² periodic field (so not periodic), heights in µm on a 0.1 µm pitch — written by
  SurfaceTopography as an ISO 25178-72 X3P file (the interchange format of areal
  instruments) and read back with ``brdfscale.topography.read``: the same path as an
  instrument file of that size;
* ``array-1000-masked``: the same heights as a NumPy array with 5 % of the pixels unmeasured
  (NaN: a dropout disc and two scan lines flagged bad), through
  ``brdfscale.topography.from_array`` (no file).

Timed for each case (seconds; median of ``--repeats`` rounds after a warm-up, the candidates
interleaved within each round so that all see the same machine):

* ``total`` — the target's figure: ``topography.read(path, detrend="curvature")`` (or
  ``from_array``) followed by ``synth.facet_statistics(field, field.scales(8))`` (129² bins:
  s(·, μ), g_μ, Σ(μ), its standard errors and facet counts at each scale);
* its parts: ``read`` (``detrend=None``), ``detrend`` (``topography.detrend(…, "curvature")``)
  and ``statistics`` (``facet_statistics`` alone);
* ``fresh_process`` (the 1000 × 1000 file only) — the same pipeline in a fresh interpreter:
  the imports, the first read and the first statistics (timed inside the child) and the
  child's whole wall time, median of three processes;
* baseline ``surface_topography``: SurfaceTopography's own pipeline at the same eight scales —
  ``open_topography(path).topography().detrend("curvature")`` and
  ``scale_dependent_statistical_property`` of the difference quotients at the distances
  ℓ = μ (variances along x and y; docs/topography.md §6 relates them to Σ(μ));
* baseline ``numpy``: the bare Σ(μ) in plain NumPy — least-squares quadratic over the
  measured pixels, forward differences, window means by reshaping (NaN-propagating, so
  windows touching an unmeasured pixel drop out) and ``np.cov`` at each scale; no
  histograms, lobes or errors. Its Σ(μ) is compared with brdfscale's (``numpy_sigma_max_rel_diff``).

Run:  flock /tmp/brdfscale-bench.lock python -m experiments.bench_topography [--repeats 5]
Writes experiments/results/bench_topography.json; docs/benchmarks.md ("Measured surfaces")
is generated from it by ``python -m experiments.benchmarks_page``.
"""

import argparse
import os
import tempfile
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

from experiments._bench import interleaved_times, machine, median, write_json


ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data" / "topographies"
FILES = {  # file → instrument / kind (tests/data/topographies/README.md)
    "di-3.di": "AFM (Bruker Dimension Icon)",
    "opd-1.opd": "optical interferometer (Veeco OPD)",
    "plu-1.plu": "confocal (Sensofar PLu neox)",
    "mi-1.mi": "AFM (Molecular Imaging)",
    "frt-1.frt": "FRT profilometer",
}
SCALES = 8
TARGET_SECONDS = 10.0
TARGET_CASE = "x3p-1000"


def synthetic_heights(size: int, seed: int = 0) -> np.ndarray:
    """``size × size`` heights in µm of a fractal random surface on a 0.1 µm pitch (cut from a
    periodic field a little larger, so the cut is not periodic)."""
    from brdfscale import stats, synth

    side = 1 << max(4, int(np.ceil(np.log2(size * 1.02))))
    field = synth.spectral_field(stats.KCorrelation(A=30.0, B=32.0, C=3.5), size=side, seed=seed)
    return field.heights[:size, :size] * 0.1  # pixel units → µm at a 0.1 µm pitch (slopes unchanged)


def with_dropouts(heights: np.ndarray, fraction: float = 0.05) -> np.ndarray:
    """A copy with about ``fraction`` of the pixels NaN, as instruments lose them: a dropout
    disc (a dust grain, a steep pit) and two scan lines flagged bad."""
    out = heights.copy()
    ny, nx = out.shape
    out[[ny // 5, (3 * ny) // 4]] = np.nan
    radius = np.sqrt(max(fraction - 2 / ny, 0.0) * ny * nx / np.pi)
    y, x = np.ogrid[:ny, :nx]
    out[(y - 0.3 * ny) ** 2 + (x - 0.6 * nx) ** 2 < radius**2] = np.nan
    return out


def numpy_sigma(heights: np.ndarray, spacing: tuple[float, float], blocks: list[tuple[int, int]]) -> list[np.ndarray]:
    """Σ(μ) in plain NumPy: quadratic removed over the measured pixels (NaN = unmeasured), the
    mean forward-difference slope of every whole window (no wrap-around), windows with a NaN
    dropped, ``np.cov`` of the rest."""
    h = np.asarray(heights, float)
    ny, nx = h.shape
    valid = np.isfinite(h)
    xi = np.broadcast_to((np.arange(nx) / nx)[None, :], h.shape)
    eta = np.broadcast_to((np.arange(ny) / ny)[:, None], h.shape)
    terms = [np.ones_like(h), xi, eta, xi**2, eta**2, xi * eta]
    coefficients, *_ = np.linalg.lstsq(np.stack([t[valid] for t in terms], -1), h[valid], rcond=None)
    h = h - sum(c * t for c, t in zip(coefficients, terms))
    dx, dy = spacing
    mx = -(h[:-1, 1:] - h[:-1, :-1]) / dx  # pixel facets (ny − 1, nx − 1); NaN where a node is unmeasured
    my = -(h[1:, :-1] - h[:-1, :-1]) / dy
    out = []
    for by, bx in blocks:
        rows, cols = mx.shape[0] // by, mx.shape[1] // bx
        wx = mx[: rows * by, : cols * bx].reshape(rows, by, cols, bx).mean(axis=(1, 3)).ravel()
        wy = my[: rows * by, : cols * bx].reshape(rows, by, cols, bx).mean(axis=(1, 3)).ravel()
        keep = np.isfinite(wx) & np.isfinite(wy)
        out.append(np.cov(np.stack([wx[keep], wy[keep]])))
    return out


def surface_topography_slopes(topo, scales_m: list[float]) -> np.ndarray:
    """SurfaceTopography's detrended (quadratic) scale-dependent slope variances along x and y
    at the distances ℓ = μ, (len(scales), 2)."""
    from brdfscale import topography

    detrended = topo.detrend("curvature")
    metres = topography.UNITS[{"µm": "\u00b5m", "μm": "\u03bcm"}.get(detrended.unit, detrended.unit)]
    distances = np.array(scales_m) / metres

    def variances(dx, dy=None):
        return np.array([np.ma.var(dx), np.ma.var(dy)])

    _, values = detrended.scale_dependent_statistical_property(variances, distance=distances, reliable=False)
    return np.asarray(values)


def case_functions(name: str, source, spacing_um=None) -> tuple[dict, dict]:
    """``(callables, description)`` of one case: the brdfscale pipeline, its parts and the baselines.

    ``source`` is a file path (read through SurfaceTopography) or an array of heights in µm
    with NaN unmeasured (``from_array`` with pitch ``spacing_um``)."""
    import SurfaceTopography as st

    from brdfscale import synth, topography

    if isinstance(source, (str, os.PathLike)):
        path = str(source)

        def load(detrend):
            return topography.read(path, detrend=detrend)

        def st_topography():
            return st.open_topography(path).topography()
    else:
        heights = np.asarray(source)

        def load(detrend):
            return topography.from_array(heights, spacing_um, unit="µm", detrend=detrend)

        def st_topography():
            (ny, nx), (dx, dy) = heights.shape, spacing_um
            return st.Topography(np.ma.masked_invalid(heights.T), (nx * dx, ny * dy), unit="µm", periodic=False)

    field = load("curvature")
    scales = field.scales(SCALES)
    blocks = [field.block(mu) for mu in scales]
    raw = load(None)
    raw_heights = np.where(raw.mask, raw.heights, np.nan) if raw.mask is not None else raw.heights

    def total():
        f = load("curvature")
        return synth.facet_statistics(f, f.scales(SCALES))

    fns = {
        "total": total,
        "read": lambda: load(None),
        "detrend": lambda: topography.detrend(raw.heights, "curvature", raw.mask),
        "statistics": lambda: synth.facet_statistics(field, scales),
        "baseline_surface_topography": lambda: surface_topography_slopes(st_topography(), scales),
        "baseline_numpy": lambda: numpy_sigma(raw_heights, field.spacing, blocks),
    }
    ours = synth.facet_statistics(field, scales)
    theirs = numpy_sigma(raw_heights, field.spacing, blocks)
    differences = [float(np.max(np.abs(a.covariance - b)) / np.max(np.abs(a.covariance))) for a, b in zip(ours, theirs)]
    st_var = surface_topography_slopes(st_topography(), scales)
    info = {
        "case": name,
        "shape": list(field.shape),
        "spacing_m": list(field.spacing),
        "unmeasured": 0 if field.mask is None else int(np.count_nonzero(~field.mask)),
        "scales_px": [int(b[1]) for b in blocks],
        "facets": [int(s.count) for s in ours],
        "excluded": [int(s.excluded) for s in ours],
        "sigma_xx": [float(s.covariance[0, 0]) for s in ours],
        "sigma_yy": [float(s.covariance[1, 1]) for s in ours],
        "surface_topography_slope_variance_x": [float(v) for v in st_var[:, 0]],
        "surface_topography_slope_variance_y": [float(v) for v in st_var[:, 1]],
        "numpy_sigma_max_rel_diff": max(differences),
    }
    return fns, info


FRESH = r"""
import json, sys, time
t0 = time.perf_counter()
import jax
jax.config.update("jax_enable_x64", True)
from brdfscale import synth, topography
import SurfaceTopography
t1 = time.perf_counter()
field = topography.read(sys.argv[1], detrend="curvature")
t2 = time.perf_counter()
synth.facet_statistics(field, field.scales(8))
t3 = time.perf_counter()
print(json.dumps({"imports_s": t1 - t0, "read_and_detrend_s": t2 - t1, "statistics_s": t3 - t2, "total_s": t3 - t0}))
"""


def fresh_process(path: Path, repeats: int) -> dict:
    """The target's pipeline in a fresh interpreter, as a script or the command line runs it:
    the imports (jax, brdfscale, SurfaceTopography), the first read and the first statistics,
    each timed inside the child; and the child's whole wall time (interpreter start included).
    Medians over ``repeats`` processes."""
    import json
    import subprocess
    import sys
    import time

    runs, walls = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-c", FRESH, str(path)], cwd=ROOT, capture_output=True, text=True, check=True
        )
        walls.append(time.perf_counter() - t0)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    result = {key: median(sorted(r[key] for r in runs)) for key in runs[0]}
    result["process_wall_s"] = median(sorted(walls))
    result["processes"] = repeats
    return result


def measure(name: str, source, repeats: int, spacing_um=None) -> dict:
    fns, info = case_functions(name, source, spacing_um)
    times = interleaved_times(fns, repeat=repeats)
    info["times_s"] = {k: [round(t, 4) for t in v] for k, v in times.items()}
    info["median_s"] = {k: median(v) for k, v in times.items()}
    return info


def run(
    *, files=tuple(FILES), size: int = 1000, repeats: int = 5, fresh: bool = True, out: str | os.PathLike | None = None
) -> dict:
    """Measure every case and write the JSON (``out``: a path; default experiments/results/bench_topography.json);
    ``fresh=False`` leaves out the fresh-interpreter runs."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import SurfaceTopography as st

    load_start = os.getloadavg()
    cases = []
    for name in files:
        record = measure(name, DATA / name, repeats)
        record.update(kind=FILES[name], source="instrument file", format=Path(name).suffix[1:])
        cases.append(record)
    heights = synthetic_heights(size)
    with tempfile.TemporaryDirectory(prefix="brdfscale-bench-") as tmp:
        path = Path(tmp) / f"synthetic-{size}.x3p"
        st.Topography(
            heights.T,
            (size * 0.1, size * 0.1),
            unit="µm",
            periodic=False,
            info={"instrument": {"name": "synthetic (brdfscale.synth.spectral_field)"}},
        ).to_x3p(str(path))
        record = measure(f"x3p-{size}", path, repeats)
        record.update(
            kind="synthetic fractal heights in an X3P file (ISO 25178-72) written by SurfaceTopography",
            source="file",
            format="x3p",
            file_bytes=path.stat().st_size,
            **({"fresh_process": fresh_process(path, max(1, min(repeats, 3)))} if fresh else {}),
        )
        cases.append(record)
    record = measure(f"array-{size}-masked", with_dropouts(heights), repeats, spacing_um=(0.1, 0.1))
    record.update(
        kind="the same heights as a NumPy array, 5 % unmeasured (NaN: a disc, two lines)",
        source="from_array",
        format=None,
    )
    cases.append(record)
    info = machine()
    for pkg in ("SurfaceTopography", "muFFT"):
        try:
            info["versions"][pkg] = version(pkg)
        except PackageNotFoundError:
            info["versions"][pkg] = None
    payload = {
        "benchmark": "reading, detrending and facet statistics at 8 scales of measured surfaces (issue 18)",
        "target": {
            "case": f"x3p-{size}",
            "seconds": TARGET_SECONDS,
            "what": "topography.read(path, detrend='curvature') + synth.facet_statistics(field, field.scales(8))",
        },
        "command": f"python -m experiments.bench_topography --repeats {repeats}"
        + (f" --size {size}" if size != 1000 else ""),
        "repeats": repeats,
        "bins": 129,
        "machine": info,
        "load_average_1min_at_start_and_end": [load_start[0], os.getloadavg()[0]],
        "cases": cases,
    }
    if out is None:
        write_json("bench_topography", payload)
    else:
        import json

        from brdfscale import files

        files.write_text(out, json.dumps(payload, indent=2) + "\n", overwrite=True)
    return payload


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="interleaved rounds per case (median reported)")
    parser.add_argument("--size", type=int, default=1000, help="pixels per side of the synthetic measurement")
    args = parser.parse_args(argv)
    payload = run(size=args.size, repeats=args.repeats)
    for c in payload["cases"]:
        m = c["median_s"]
        print(
            f"{c['case']:>20} {c['shape'][0]:4d}×{c['shape'][1]:<4d} total {m['total']:6.2f} s "
            f"(read {m['read']:.2f}, detrend {m['detrend']:.2f}, statistics {m['statistics']:.2f}); "
            f"SurfaceTopography {m['baseline_surface_topography']:.2f} s, NumPy Σ only {m['baseline_numpy']:.2f} s"
        )


if __name__ == "__main__":
    main()
