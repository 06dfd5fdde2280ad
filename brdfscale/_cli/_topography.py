"""``brdfscale topography FILE --out DIR``: the scale-dependent slope statistics of a measured surface.

Reads an instrument height map (:func:`brdfscale.topography.read`), measures
:func:`brdfscale.synth.facet_statistics` at the requested scales and writes into DIR
``statistics.json`` (provenance and, per scale, μ, facet counts, Σ(μ) with its standard error),
``statistics.md`` (the same as a readable table) and ``statistics.png`` (Σ(μ) against μ beside
cuts through the within-facet lobes g_μ), and prints the table. The options that read a
topography (``--channel``, ``--detrend``) are shared with ``brdfscale synth --topography``
(:func:`add_reading_options`, :func:`read_field`).
"""

import math
import os

from .._errors import InvalidInputError
from .._json import json_text, jsonable
from .._show import display_unit
from ._options import integer, make_directory, output_directory, scales


#: What the command writes into --out, in the order it writes them (the JSON last: it is
#: written when everything else is in place).
OUTPUTS = ("statistics.png", "statistics.md", "statistics.json")
DETRENDS = ("plane", "curvature", "none")
#: Units μ is shown in (the one that puts the largest scale in [1, 1000)).


def channel(text: str):
    """An option type: a data channel by index (a whole number) or by name."""
    return int(text) if text.isascii() and text.isdigit() else text


def add_reading_options(parser) -> None:
    """``--channel`` and ``--detrend``: how a topography file is read (``topography``, ``synth``)."""
    parser.add_argument(
        "--channel",
        type=channel,
        default=None,
        metavar="C",
        help="data channel of the file, by index or name (default: the file's height channel; a wrong "
        "one is refused with the file's channels listed)",
    )
    parser.add_argument(
        "--detrend",
        choices=DETRENDS,
        default=None,
        help="trend removed from the heights by least squares over the measured pixels before the "
        "statistics: plane (default: tilt), curvature (a quadratic) or none; recorded in the provenance",
    )


def _detrend(args) -> str:
    return args.detrend if args.detrend is not None else "plane"  # None: not given (synth refuses it without a file)


def read_field(path: str, args, micro=None):
    """The measured :class:`brdfscale.synth.HeightField` of ``path`` read with ``args.channel``
    and ``args.detrend`` (lengths in metres; provenance in ``field.description``)."""
    from .. import topography

    mode = _detrend(args)
    return topography.read(path, channel=args.channel, detrend=None if mode == "none" else mode, micro=micro)


def reading_command(args) -> str:
    """The reading options as they would be typed (for a record of the command)."""
    parts = [] if args.channel is None else ["--channel", str(args.channel)]
    return " ".join(parts + ["--detrend", _detrend(args)])


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "topography",
        help="measure the scale-dependent slope statistics Σ(μ) and lobes g_μ of a measured height map",
        description="Read an instrument height map (AFM, interferometer, confocal microscope, profilometer: "
        "the formats of SurfaceTopography, the optional extra brdfscale[topography]), measure the facet-slope "
        "covariance Σ(μ), its standard error, the facet counts and the within-facet lobes g_μ at each scale μ, "
        "and write DIR/statistics.json, DIR/statistics.md and DIR/statistics.png. Lengths are in metres.",
    )
    parser.add_argument("file", metavar="FILE", help="instrument height map (e.g. .di, .mi, .opd, .plu, .frt)")
    add_reading_options(parser)
    parser.add_argument(
        "--scales",
        type=scales,
        default=scales("auto:8"),
        metavar="SCALES",
        help="facet sizes μ, comma-separated: lengths with a unit (0.5um, 1e-6m, 0.1mm; units m, mm, "
        "um or µm, nm, Å, …) or pixel counts (1px,4px,16px), each a whole number of pixels; or "
        "auto[:COUNT]: COUNT log-spaced whole pixel counts up to half the field (default auto:8)",
    )
    parser.add_argument(
        "--bins",
        type=integer(2, 4097),
        default=129,
        help="nodes per axis of the tabulated lobes g_μ, 2–4097 (default 129)",
    )
    parser.add_argument(
        "--out",
        required=True,
        help="output directory (created; statistics.json, .md, .png); one "
        "run at a time: a second run into it is refused (exit 3)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite the statistics files in --out")
    parser.set_defaults(func=run)


def _refuse_existing(out: str, force: bool) -> None:
    existing = [name for name in OUTPUTS if os.path.lexists(os.path.join(out, name))]
    if existing and not force:
        raise InvalidInputError(
            f"--out {out} already holds {', '.join(existing)}; choose another --out directory or "
            "pass --force to replace them."
        )


def run(args) -> int:
    from .. import files, plot, synth

    output_directory(args.out)
    _refuse_existing(args.out, args.force)  # before the work; again under the lock
    field = read_field(args.file, args)
    mus = sorted(args.scales.resolve(field))
    extent = lobe_extent(field)
    results = synth.facet_statistics(field, mus, bins=args.bins, extent=extent)
    command = f"brdfscale topography {args.file} {reading_command(args)} --scales {args.scales} --bins {args.bins}"
    doc = document(field, results, args.bins, command, extent)
    fig = plot.facet_statistics(results, field=field)
    make_directory(args.out)
    with files.exclusive(args.out, what="output directory"):
        _refuse_existing(args.out, args.force)
        png, md, js = (os.path.join(args.out, name) for name in OUTPUTS)
        with files.all_or_none(png, md, js):  # a full disk at the last file: none left, a rerun needs no --force
            files.atomic_write(png, lambda tmp: fig.savefig(tmp, dpi=120, format="png"), overwrite=args.force)
            files.write_text(md, markdown(doc), overwrite=args.force)
            files.write_text(js, json_text(doc, indent=2, ensure_ascii=False) + "\n", overwrite=args.force)
    print(summary_line(doc))
    print(table(doc))
    print(f"wrote {js}, {os.path.basename(md)} and {os.path.basename(png)}")
    return 0


def lobe_extent(field) -> float | None:
    """The half-width of the lobes' grids g_μ (the figure's cuts): :func:`brdfscale.synth.robust_extent`,
    from quantiles of the pixel slopes, so that a few outlier pixels do not squeeze every lobe into a
    node; None (the full range of :func:`brdfscale.synth.facet_statistics`) for a field whose slopes do
    not vary at that quantile (a flat one). Σ(μ) does not depend on it: it is computed from the facets."""
    from .. import synth

    if field.steepest_slope == 0:
        return None
    try:
        return synth.robust_extent(field)
    except InvalidInputError:  # fewer than 1 % of the pixel facets deviate from the mean slope
        return None


def document(field, results, bins: int, command: str, extent: float | None = None) -> dict:
    """statistics.json's content: provenance, the field's geometry and per scale the statistics."""
    from .. import __version__, topography

    dx, dy = field.spacing
    measured = field.heights.size if field.mask is None else int(field.mask.sum())
    return {
        "format": "brdfscale topography statistics",
        "version": 1,
        "brdfscale": __version__,
        "command": command,
        "topography": field.description,
        "field": {
            "shape": list(field.shape),
            "spacing_m": [dx, dy],
            "unit": field.unit,
            "periodic": field.periodic,
            "measured_pixels": measured,
            "unmeasured_pixels": field.heights.size - measured,
            "steepest_pixel_slope": field.steepest_slope,
            "flat": field.steepest_slope == 0,
            # pitches equal to a relative 1e-3 made square: the pitches as given and their difference
            "square_pixels": field.description.get("square_pixels"),
            # the few pixel slopes that can carry nearly all of Σ (topography.slope_outliers)
            "slope_outliers": topography.slope_outliers(field).to_json(),
        },
        "bins": bins,
        "lobe_extent": extent,  # the half-width of the g_μ grids (null: the full range of the slopes)
        "conventions": "slopes are normal slopes m = −∇h (dimensionless); a facet at scale μ is a window of block = "
        "(rows, cols) = (μ/Δy, μ/Δx) pixel facets placed without wrap-around, window_m its sides along x and "
        "y (equal to μ within 1e-3 when the pixels are not square); mean and covariance are "
        "those of the facet slopes (covariance: the unbiased sample covariance Σ(μ)), covariance_error "
        "the standard error of each entry (null where undefined), independent the effective number of "
        "independent facets, excluded the windows touching an unmeasured pixel, rms_slope √⟨|m|²⟩ "
        "over the facets",
        "scales": [
            {
                "mu_m": r.mu,
                "mu_px": r.block[1],
                "block": list(r.block),
                "window_m": list(r.window),
                "count": r.count,
                "excluded": r.excluded,
                # lists, None where not finite (e.g. the error of a single facet's Σ)
                "independent": r.independent,
                "mean": r.mean.tolist(),
                "covariance": jsonable(r.covariance),
                "covariance_error": jsonable(r.covariance_error),
                "rms_slope": r.rms_slope,
            }
            for r in results
        ],
    }


def _sigma(row) -> tuple[list[float], list[float]]:
    """σ_x, σ_y and their standard errors (from those of Σ_xx, Σ_yy: δσ = δΣ / 2σ)."""
    cov, err = row["covariance"], row["covariance_error"]
    sd = [math.sqrt(max(cov[a][a], 0.0)) for a in (0, 1)]
    de = [
        err[a][a] / (2 * s) if err[a][a] is not None and s > 0 else 0.0 if err[a][a] == 0 else math.nan
        for a, s in zip((0, 1), sd)
    ]
    return sd, de


def summary_line(doc: dict) -> str:
    d, f = doc["topography"], doc["field"]
    (ny, nx), (dx, dy) = f["shape"], f["spacing_m"]
    unit, size = display_unit([dx])
    instrument = (
        (d.get("instrument") or {}).get("name") if isinstance(d.get("instrument"), dict) else d.get("instrument")
    )
    ch = d.get("channel") or {}
    trend = d.get("detrend") or "none"
    square, flat = f.get("square_pixels"), f.get("flat")
    return (
        f"{d.get('file', '?')}: {ny} × {nx} pixels of {dx / size:.4g} × {dy / size:.4g} {unit}"
        + (f", {instrument}" if instrument else "")
        + f", channel {ch.get('index')} {ch.get('name')!r}"
        + f", detrend {trend}, {f['unmeasured_pixels']} unmeasured pixels"
        + (f"\n{square_note(square)}" if square else "")
        + (f"\n{quantum_note(d['height_quantum'], dx, dy)}" if d.get("height_quantum") else "")
        + (f"\n{outliers}" if (outliers := outliers_note(f)) else "")
        + ("\nnote: the surface is flat (every measured pixel slope is 0): Σ(μ) = 0 at every scale" if flat else "")
    )


def quantum_note(quantum: float, dx: float, dy: float) -> str:
    """One line: the file's heights on a lattice (:func:`brdfscale.topography.height_quantum`), its slope quantum."""
    return (
        f"note: heights quantised in steps of {quantum:.4g} m: pixel slopes on a lattice of {quantum / dx:.4g} "
        f"(x) × {quantum / dy:.4g} (y), so the lobes g_μ are combs of spikes that far apart (brdfscale synth "
        "--topography blurs its lobes by one quantum by default where that exceeds 2 image pixels)"
    )


def outliers_note(field_record: dict) -> str | None:
    """One line where a few pixel slopes carry most of Σ (:meth:`brdfscale.topography.SlopeOutliers.note`; None
    otherwise, and for statistics.json written before the record)."""
    from .. import topography

    record = field_record.get("slope_outliers")
    if not record:
        return None
    return topography.SlopeOutliers.from_json(record).note()


def square_note(record: dict) -> str:
    """One line: pitches equal to the tolerance, treated as square, with their difference."""
    unit, size = display_unit([record["pitch"]])
    dx, dy = record["pitch_as_given"]
    return (
        f"note: pixels square to {100 * record['relative_difference']:.2g} % (Δx = {dx / size:.6g}, Δy = "
        f"{dy / size:.6g} {unit} in the file), within the tolerance {100 * record['tolerance']:g} %: treated as "
        f"square, Δ = {record['pitch'] / size:.6g} {unit} (√(Δx Δy); recorded in statistics.json)"
    )


def _rows(doc: dict) -> tuple[str, list[list[str]]]:
    unit, size = display_unit([r["mu_m"] for r in doc["scales"]])
    rows = []
    for r in doc["scales"]:
        (sx, sy), (ex, ey) = _sigma(r)
        rows.append(
            [
                f"{r['mu_m'] / size:.4g}",
                str(r["mu_px"]),
                "×".join(map(str, r["block"])),
                str(r["count"]),
                f"{r['independent']:.1f}",
                str(r["excluded"]),
                f"{sx:.4g} ± {ex:.2g}",
                f"{sy:.4g} ± {ey:.2g}",
                f"{r['covariance'][0][1]:.3g}",
                f"{r['rms_slope']:.4g}",
            ]
        )
    return unit, rows


def table(doc: dict) -> str:
    """The compact table printed on stdout."""
    unit, rows = _rows(doc)
    head = [f"μ ({unit})", "px", "block", "facets", "indep.", "excl.", "σ_x ± err", "σ_y ± err", "Σ_xy", "rms slope"]
    widths = [max(len(h), *(len(r[k]) for r in rows)) for k, h in enumerate(head)]
    line = lambda cells: "  " + "  ".join(c.rjust(w) for c, w in zip(cells, widths))
    return "\n".join([line(head)] + [line(r) for r in rows])


def markdown(doc: dict) -> str:
    """statistics.md: the provenance and the table."""
    d, f = doc["topography"], doc["field"]
    unit, rows = _rows(doc)
    trend = d.get("trend") or {}
    lines = [
        f"# Facet-slope statistics of {d.get('file', 'a topography')}",
        "",
        f"Written by `{doc['command']}` (brdfscale {doc['brdfscale']}).",
        "",
    ]
    for key, label in (
        ("path", "file"),
        ("format", "format"),
        ("reader", "reader"),
        ("instrument", "instrument"),
        ("channel", "channel"),
        ("file_unit", "unit of the file"),
        ("acquisition_time", "acquired"),
    ):
        if d.get(key) not in (None, "", {}):
            value = d[key]
            if isinstance(value, dict):
                value = ", ".join(f"{k}: {v}" for k, v in value.items())
            lines.append(f"* {label}: {value}")
    lines += [
        (
            f"* field: {f['shape'][0]} × {f['shape'][1]} pixels (rows y × columns x), pitch Δx = "
            f"{f['spacing_m'][0]:.6g} m, Δy = {f['spacing_m'][1]:.6g} m; {f['unmeasured_pixels']} unmeasured "
            f"pixels; steepest pixel slope component {f['steepest_pixel_slope']:.4g}"
        ),
        f"* detrend: {trend.get('mode') or 'none'}"
        + (
            f" (terms {', '.join(trend['terms'])}; coefficients "
            f"{', '.join(f'{c:.6g}' for c in trend['coefficients'])}, "
            "in metres)"
            if trend.get("coefficients")
            else ""
        ),
        *([f"* {square_note(f['square_pixels'])[6:]}"] if f.get("square_pixels") else []),
        *(
            [f"* {quantum_note(doc['topography']['height_quantum'], *f['spacing_m'])[6:]}"]
            if doc["topography"].get("height_quantum")
            else []
        ),
        *(["* the surface is flat: every measured pixel slope is 0"] if f.get("flat") else []),
        *([f"* {outliers[6:]}"] if (outliers := outliers_note(f)) else []),
        f"* lobes g_μ tabulated on {doc['bins']} × {doc['bins']} nodes"
        + (f" over ±{doc['lobe_extent']:.4g} (synth.robust_extent)" if doc.get("lobe_extent") else ""),
        "",
    ]
    head = [
        f"μ ({unit})",
        "μ (px)",
        "block (rows×cols)",
        "facets",
        "independent",
        "excluded",
        "σ_x ± error",
        "σ_y ± error",
        "Σ_xy",
        "rms slope",
    ]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    lines += [
        "",
        (
            "σ_a = √Σ_aa (Σ(μ): the unbiased sample covariance of the facets' normal slopes m = −∇h); the "
            "error is the standard error of Σ_aa carried to σ_a (δσ = δΣ/2σ), with the facets' correlation "
            "over the facet lattice (the effective number of independent facets). Excluded: windows touching "
            "an unmeasured pixel. The full covariances and their errors are in statistics.json."
        ),
        "",
    ]
    return "\n".join(lines)
