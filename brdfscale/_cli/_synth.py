"""``brdfscale synth SURFACE --out FILE.exr``: a synthetic measurement set from a built-in surface."""

import argparse
import math

from .._errors import InvalidInputError
from ._options import MAX_SEED, integer, output_file, real, seed


def _scales(text: str) -> list[float]:
    """Comma-separated facet sizes μ: 1–64 whole numbers of pixels ≥ 1 (each ≤ --size, checked
    with the size)."""
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers; got {text!r:.60}") from None
    if not 1 <= len(values) <= 64 or not all(math.isfinite(v) and v >= 1 and v == round(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected 1–64 comma-separated whole numbers of pixels ≥ 1; got {text!r:.60}")
    return values


def _incident(text: str) -> tuple[float, float, float]:
    """``THETA`` or ``THETA:PHI`` (degrees) → unit vector towards the light."""
    try:
        angles = [float(x) for x in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected THETA or THETA:PHI in degrees; got {text!r:.60}") from None
    if len(angles) not in (1, 2) or not 0 <= angles[0] < 90 or not all(math.isfinite(a) for a in angles):
        raise argparse.ArgumentTypeError(f"expected THETA (0 ≤ θ < 90) or THETA:PHI in degrees (finite); got {text!r:.60}")
    theta, phi = math.radians(angles[0]), math.radians(angles[1] if len(angles) == 2 else 0.0)
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


#: Domains of the noise parameters: the lobe images are stored as float32 (|x| ≤ 3.4e38).
_EXPOSURE, _SIGMA, _READ = (1e-6, 1e15), (1e-30, 1e30), (0.0, 1e6)


def _noise(text: str):
    from .. import synth

    kind, _, value = text.partition(":")
    if kind == "none" and not value:
        return None
    if kind in ("poisson", "gaussian"):
        lo, hi = _EXPOSURE if kind == "poisson" else _SIGMA
        value, _, read = value.partition(":") if kind == "poisson" else (value, "", "")
        number = real(lo, hi)(value)
        read_noise = real(*_READ)(read) if read else 0.0
        try:
            return synth.PoissonNoise(number, read_noise) if kind == "poisson" else synth.GaussianNoise(floor=number)
        except InvalidInputError as err:
            raise argparse.ArgumentTypeError(f"bad noise {text!r:.60}: {err}") from None
    raise argparse.ArgumentTypeError(f"noise must be none, poisson:EXPOSURE[:READ_NOISE] (EXPOSURE in [{_EXPOSURE[0]:g}, "
                                     f"{_EXPOSURE[1]:g}], READ_NOISE in counts in [0, {_READ[1]:g}]) or gaussian:SIGMA (SIGMA in [{_SIGMA[0]:g}, {_SIGMA[1]:g}]); "
                                     f"got {text!r:.60}")


def register(subparsers) -> None:
    from .._surfaces import DESCRIPTIONS as SURFACES

    parser = subparsers.add_parser(
        "synth",
        help="write a synthetic multi-scale measurement set from a built-in surface",
        description="Simulate a gonioreflectometer on a built-in random surface and write the lobe images "
        "as a multi-part OpenEXR measurement set. Lengths and scales are in pixels.",
        epilog="surfaces: " + "; ".join(f"{name}: {desc}" for name, desc in SURFACES.items()),
    )
    parser.add_argument("surface", choices=sorted(SURFACES), metavar="SURFACE", help="one of: " + ", ".join(SURFACES))
    parser.add_argument("--out", required=True, help="output .exr file")
    parser.add_argument("--scales", type=_scales, default=[4.0, 16.0, 64.0],
                        help="facet sizes μ, whole numbers of pixels from 1 to --size (default 4,16,64)")
    parser.add_argument("--incident", type=_incident, action="append", metavar="THETA[:PHI]",
                        help="incident direction in degrees; repeat for several (default 0)")
    parser.add_argument("--noise", type=_noise, default=None, metavar="MODEL",
                        help="none (default), poisson:EXPOSURE[:READ_NOISE] (counts per unit lobe value; optional Gaussian "
                        "read noise in counts, which makes σ exact in dark pixels) or gaussian:SIGMA")
    parser.add_argument("--resolution", type=real(0.0, 10.0), default=0.0, help="instrument blur, slope std, 0–10 (default 0)")
    parser.add_argument("--micro-alpha", type=real(0.0, 10.0, strict_lo=True), default=None, metavar="ALPHA",
                        help="Beckmann roughness of the pixel facets, in (0, 10] (default: mirror facets)")
    parser.add_argument("--extent", type=real(0.0, 1000.0, strict_lo=True), default=None,
                        help="image half-width in slope units, in (0, 1000] (default: 1.05 × steepest pixel slope)")
    parser.add_argument("--pixels", type=integer(3, 1025), default=65, help="image nodes per axis, 3–1025 (default 65)")
    parser.add_argument("--size", type=integer(16, 4096), default=512, help="height field pixels per side, 16–4096 (default 512)")
    parser.add_argument("--seed", type=seed, default=0, help=f"random seed of surface and noise, 0–{MAX_SEED} (default 0)")
    parser.add_argument("--weighting", choices=("nearly_flat", "projected_area"), default="nearly_flat",
                        help="pixel-facet weighting (default nearly_flat, the seed's approximation)")
    parser.add_argument("--dtype", choices=("float32", "float16"), default="float32", help="pixel type (default float32)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output file")
    parser.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from .. import exr, stats, synth

    output_file(args.out, args.force)
    if max(args.scales) > args.size:
        raise InvalidInputError(f"--scales {max(args.scales):g} exceeds the field's --size {args.size}: a facet cannot "
                                "be larger than the surface.")
    surface_seed, noise_seed = np.random.SeedSequence(args.seed).spawn(2)
    micro = None if args.micro_alpha is None else stats.Beckmann(args.micro_alpha)
    field = synth.named_surface(args.surface, size=args.size, seed=np.random.default_rng(surface_seed), micro=micro)
    field = synth.HeightField(field.heights, field.spacing, micro=field.micro, spectrum=field.spectrum,
                              description={**field.description, "seed": args.seed})
    extent = args.extent if args.extent is not None else 1.05 * synth.steepest_slope(field)
    incident = np.array(args.incident) if args.incident else np.array([[0.0, 0.0, 1.0]])
    mset = synth.gonioreflectometer(
        field, args.scales, incident, extent=extent, pixels=args.pixels, noise=args.noise,
        resolution=args.resolution, weighting=args.weighting,
        seed=np.random.default_rng(noise_seed) if args.noise is not None else None,
    )
    mset.metadata["seed"] = args.seed
    mset.metadata["command"] = f"brdfscale synth {args.surface}"
    exr.write_measurements(args.out, mset, overwrite=args.force, dtype=args.dtype)
    print(f"wrote {args.out}: {len(mset.images)} lobe images ({args.surface}, {args.size}² field, scales {args.scales})")
    return 0
