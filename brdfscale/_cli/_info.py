"""``brdfscale info FILE.exr``: summarise a measurement set or lobe table."""

import math

from .._json import json_text


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "info",
        help="summarise a brdfscale OpenEXR file (measurement set or lobe table)",
        description="Read and validate a brdfscale OpenEXR file and print what it holds.",
    )
    parser.add_argument("file", help="a .exr file written by brdfscale")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(func=run, compiles=False)  # reads headers and pixels: no JAX, no cache


def _angles(incident) -> tuple[float, float]:
    x, y, z = (float(c) for c in incident)
    return math.degrees(math.acos(min(1.0, z))), math.degrees(math.atan2(y, x)) % 360


def summarise(path) -> dict:
    """A JSON-friendly summary of the file (everything validated by the readers)."""
    from .. import exr

    kind = exr.file_kind(path)
    if kind == "lobe_table":
        table = exr.read_lobe_table(path)
        return {
            "file": str(path),
            "kind": kind,
            "parts": len(table.scales),
            "scales": table.scales.tolist(),
            "extent": table.extent,
            "pixels": table.values.shape[1],
            "channels": "RGB" if table.values.ndim == 4 else "Y",
            "value_range": [float(table.values.min()), float(table.values.max())],
            "metadata_keys": sorted(table.metadata),
        }
    mset = exr.read_measurements(path)
    images = []
    for p in mset.images:
        theta, phi = _angles(p.incident)
        images.append(
            {
                "mu": p.mu,
                "theta_deg": theta,
                "phi_deg": phi,
                "extent": p.extent,
                "pixels": p.size,
                "channels": "RGB" if p.values.ndim == 3 else "Y",
                "sigma": p.sigma is not None,
                "mask": p.mask is not None,
                "value_range": [float(p.values.min()), float(p.values.max())],
            }
        )
    meta = mset.metadata
    return {
        "file": str(path),
        "kind": kind,
        "parts": len(mset.images),
        "scales": mset.scales.tolist(),
        "incident_deg": sorted({(round(i["theta_deg"], 6), round(i["phi_deg"], 6)) for i in images}),
        "surface": _surface(meta.get("surface")),
        "metadata_keys": sorted(meta),
        "images": images,
    }


def run(args) -> int:
    summary = summarise(args.file)
    if args.json:
        print(json_text(summary, indent=2))
        return 0
    print(f"{summary['file']}: {summary['kind']}, {summary['parts']} parts")
    print(f"  scales μ: {', '.join(f'{m:g}' for m in summary['scales'])}")
    if summary["kind"] == "lobe_table":
        print(f"  grid: {summary['pixels']}² nodes over ±{summary['extent']:g}, channels {summary['channels']}")
        print(f"  values: [{summary['value_range'][0]:.4g}, {summary['value_range'][1]:.4g}]")
    else:
        if summary["surface"]:
            print(f"  surface: {summary['surface']}")
        print("  incident (θ, φ) in degrees: " + ", ".join(f"({t:g}, {p:g})" for t, p in summary["incident_deg"]))
        print("  part  mu        theta   phi     extent     pixels ch   sigma mask  max value")
        for k, im in enumerate(summary["images"]):
            print(
                f"  {k:<5d} {im['mu']:<9.4g} {im['theta_deg']:<7.3g} {im['phi_deg']:<7.3g} {im['extent']:<10.4g} "
                f"{im['pixels']:<6d} {im['channels']:<4} {'yes' if im['sigma'] else 'no':<5} "
                f"{'yes' if im['mask'] else 'no':<5} {im['value_range'][1]:.4g}"
            )
    if summary["metadata_keys"]:
        print(f"  metadata: {', '.join(summary['metadata_keys'])}")
    return 0


def _surface(record) -> str | None:
    """The surface a measurement set was made of: a built-in name, or a measured file (brdfscale.topography)."""
    if not isinstance(record, dict):
        return None
    if isinstance(record.get("name"), str):
        return record["name"]
    if isinstance(record.get("file"), str):
        instrument = record.get("instrument")
        name = instrument.get("name") if isinstance(instrument, dict) else None
        return f"{record['file']} (measured{', ' + str(name) if name else ''}, detrend {record.get('detrend')})"
    return None
