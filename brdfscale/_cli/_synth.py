"""``brdfscale synth SURFACE --out FILE.exr``: a synthetic measurement set from a built-in surface."""

import argparse
import math

import numpy as np

from .._errors import InvalidInputError


def _floats(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers; got {text!r}") from None


def _incident(text: str) -> np.ndarray:
    """``THETA`` or ``THETA:PHI`` (degrees) → unit vector towards the light."""
    try:
        angles = [float(x) for x in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected THETA or THETA:PHI in degrees; got {text!r}") from None
    if len(angles) not in (1, 2) or not 0 <= angles[0] < 90:
        raise argparse.ArgumentTypeError(f"expected THETA (0 ≤ θ < 90) or THETA:PHI in degrees; got {text!r}")
    theta, phi = math.radians(angles[0]), math.radians(angles[1] if len(angles) == 2 else 0.0)
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def _noise(text: str):
    from .. import synth

    kind, _, value = text.partition(":")
    try:
        if kind == "none" and not value:
            return None
        if kind == "poisson":
            return synth.PoissonNoise(float(value))
        if kind == "gaussian":
            return synth.GaussianNoise(floor=float(value))
    except (ValueError, InvalidInputError) as err:
        raise argparse.ArgumentTypeError(f"bad noise {text!r}: {err}") from None
    raise argparse.ArgumentTypeError(f"noise must be none, poisson:EXPOSURE or gaussian:SIGMA; got {text!r}")


def register(subparsers) -> None:
    from ..synth import SURFACES

    parser = subparsers.add_parser(
        "synth",
        help="write a synthetic multi-scale measurement set from a built-in surface",
        description="Simulate a gonioreflectometer on a built-in random surface and write the lobe images "
        "as a multi-part OpenEXR measurement set. Lengths and scales are in pixels.",
        epilog="surfaces: " + "; ".join(f"{name}: {desc}" for name, (desc, _) in SURFACES.items()),
    )
    parser.add_argument("surface", choices=sorted(SURFACES), metavar="SURFACE", help="one of: " + ", ".join(SURFACES))
    parser.add_argument("--out", required=True, help="output .exr file")
    parser.add_argument("--scales", type=_floats, default=[4.0, 16.0, 64.0], help="facet sizes μ in pixels (default 4,16,64)")
    parser.add_argument("--incident", type=_incident, action="append", metavar="THETA[:PHI]",
                        help="incident direction in degrees; repeat for several (default 0)")
    parser.add_argument("--noise", type=_noise, default=None, metavar="MODEL",
                        help="none (default), poisson:EXPOSURE (counts per unit lobe value) or gaussian:SIGMA")
    parser.add_argument("--resolution", type=float, default=0.0, help="instrument blur, slope std (default 0)")
    parser.add_argument("--micro-alpha", type=float, default=None, metavar="ALPHA",
                        help="Beckmann roughness of the pixel facets (default: mirror facets)")
    parser.add_argument("--extent", type=float, default=None, help="image half-width in slope units (default: 1.05 × steepest pixel slope)")
    parser.add_argument("--pixels", type=int, default=65, help="image nodes per axis (default 65)")
    parser.add_argument("--size", type=int, default=512, help="height field pixels per side (default 512)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of surface and noise (default 0)")
    parser.add_argument("--weighting", choices=("nearly_flat", "projected_area"), default="nearly_flat",
                        help="pixel-facet weighting (default nearly_flat, the seed's approximation)")
    parser.add_argument("--dtype", choices=("float32", "float16"), default="float32", help="pixel type (default float32)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing output file")
    parser.set_defaults(func=run)


def run(args) -> int:
    from .. import exr, stats, synth

    if args.seed < 0:
        raise InvalidInputError(f"--seed must be ≥ 0; got {args.seed}.")
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
