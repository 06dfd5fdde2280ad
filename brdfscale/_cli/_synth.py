"""``brdfscale synth SURFACE --out FILE.exr``: a synthetic measurement set from a built-in surface;
``brdfscale synth --topography FILE --out FILE.exr``: the same of a measured height map.

Two instruments: ``--instrument facets`` (the default) builds the lobes from facet statistics
(:func:`brdfscale.synth.gonioreflectometer`, the seed's nearly-flat assumptions); ``--instrument raytraced``
ray-traces the height field in Mitsuba 3 (:func:`brdfscale.instrument.measure`: masking, shadowing and
interreflection by visibility rays; σ is the Monte Carlo standard error; needs the extra ``brdfscale[render]``, a
missing Mitsuba or LLVM named in one line with exit status 2 before any work).

Defaults made for ``brdfscale fit`` (README's measured-surface chain): the image half-width from
robust slope quantiles (:func:`brdfscale.synth.robust_extent`, never the steepest pixel); with
--topography, Poisson noise with read noise (:data:`TOPOGRAPHY_NOISE`: every image stores σ) and
an instrument resolution of :data:`TOPOGRAPHY_RESOLUTION` image pixels (a mirror pixel facet's lobe
at the finest scale is then a resolved spot), or of the file's slope quantum where its heights are quantised
and that is larger (:func:`default_resolution`). Each choice is recorded in the file's metadata
(``defaults``).
"""

import argparse
import math

from .._choices import INSTRUMENTS, MICRO_FACETS, MIN_FIT_SCALES, WEIGHTINGS
from .._errors import InvalidInputError
from ._options import integer, MAX_SEED, output_file, real, scales, seed
from ._topography import add_reading_options, read_field, reading_command


_SIZE, _SEED = 512, 0  # the defaults of --size and --seed (None in the namespace: given or not)
TOPOGRAPHY_NOISE = "poisson:200:1"
"""--noise's default with --topography: 200 counts per unit lobe value and 1 count of Gaussian read noise."""
TOPOGRAPHY_RESOLUTION = 2.0
"""--resolution's default with --topography, in image pixel pitches ``2·extent/(pixels − 1)``."""


def default_resolution(field, extent: float, pixels: int) -> tuple[float, str]:
    """--resolution's default with --topography and the metadata's words for it: :data:`TOPOGRAPHY_RESOLUTION`
    image pixels, or the field's slope quantum where that is larger — the height step of a quantised file
    (``field.description["height_quantum"]``, :func:`brdfscale.topography.height_quantum`) over the smaller pixel
    pitch. Its pixel slopes lie on a lattice of that step, so its within-facet lobes are combs of spikes one
    quantum apart, the instrument's digitisation rather than the surface's; a Gaussian blur of one quantum's
    standard deviation leaves of the comb a relative ripple of 2·exp(−2π²) ≈ 5e-9. On tests/data's plu-1 (a
    quantum of 4.8 image pixels) the coarse lobe's spectrum at the comb's frequency is above 3 % of its mass with
    2 image pixels and below 1e-4 with one quantum (tests/test_topography.py)."""
    pixel = TOPOGRAPHY_RESOLUTION * 2 * extent / (pixels - 1)
    quantum = field.description.get("height_quantum")
    slope_quantum = 0.0 if quantum is None else quantum / min(field.spacing)
    if slope_quantum > pixel:
        return slope_quantum, (
            f"the slope quantum (height step {quantum:.4g} m / pitch {min(field.spacing):.4g} m), above "
            f"{TOPOGRAPHY_RESOLUTION:g} image pixels: {slope_quantum:.6g}"
        )
    return pixel, f"{TOPOGRAPHY_RESOLUTION:g} image pixels: {pixel:.6g}"


def _incident(text: str) -> tuple[float, float, float]:
    """``THETA`` or ``THETA:PHI`` (degrees) → unit vector towards the light."""
    try:
        angles = [float(x) for x in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected THETA or THETA:PHI in degrees; got {text!r:.60}") from None
    if len(angles) not in (1, 2) or not 0 <= angles[0] < 90 or not all(math.isfinite(a) for a in angles):
        raise argparse.ArgumentTypeError(
            f"expected THETA (0 ≤ θ < 90) or THETA:PHI in degrees (finite); got {text!r:.60}"
        )
    theta, phi = math.radians(angles[0]), math.radians(angles[1] if len(angles) == 2 else 0.0)
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


#: Domains of the noise parameters: the lobe images are stored as float32 (|x| ≤ 3.4e38).
_EXPOSURE, _SIGMA, _READ = (1e-6, 1e15), (1e-30, 1e30), (0.0, 1e6)


def _noise(text: str):
    from .. import synth

    kind, _, value = text.partition(":")
    if kind == "none" and not value:
        return "none"  # given: distinct from None, --noise left out
    if kind in ("poisson", "gaussian"):
        lo, hi = _EXPOSURE if kind == "poisson" else _SIGMA
        value, _, read = value.partition(":") if kind == "poisson" else (value, "", "")
        number = real(lo, hi)(value)
        read_noise = real(*_READ)(read) if read else 0.0
        try:
            return synth.PoissonNoise(number, read_noise) if kind == "poisson" else synth.GaussianNoise(floor=number)
        except InvalidInputError as err:
            raise argparse.ArgumentTypeError(f"bad noise {text!r:.60}: {err}") from None
    raise argparse.ArgumentTypeError(
        f"noise must be none, poisson:EXPOSURE[:READ_NOISE] (EXPOSURE in [{_EXPOSURE[0]:g}, "
        f"{_EXPOSURE[1]:g}], READ_NOISE in counts in [0, {_READ[1]:g}]) "
        f"or gaussian:SIGMA (SIGMA in [{_SIGMA[0]:g}, {_SIGMA[1]:g}]); "
        f"got {text!r:.60}"
    )


_RAYTRACED_ONLY = ("--rays", "--bounces", "--variant", "--micro", "--workers", "--address")
_FACETS_ONLY = ("--noise", "--resolution", "--weighting")
_RAYTRACED_WHY = " (the ray tracer's σ is its Monte Carlo error, its resolution its detector's)."


def register(subparsers) -> None:
    from .._surfaces import DESCRIPTIONS as SURFACES

    parser = subparsers.add_parser(
        "synth",
        help="write a synthetic multi-scale measurement set from a built-in surface or a measured topography",
        description="Simulate a gonioreflectometer on a built-in random surface (SURFACE) or on a measured height "
        "map (--topography FILE; give one of the two) and write the lobe images as a multi-part OpenEXR measurement "
        "set. A built-in surface's lengths and scales are in pixels; a topography's in metres.",
        epilog="surfaces: " + "; ".join(f"{name}: {desc}" for name, desc in SURFACES.items()),
    )
    parser.add_argument(
        "surface",
        nargs="?",
        choices=sorted(SURFACES),
        metavar="SURFACE",
        help="one of: " + ", ".join(SURFACES) + " (or --topography FILE instead)",
    )
    parser.add_argument(
        "--topography",
        metavar="FILE",
        default=None,
        help="instead of SURFACE: an instrument height map (brdfscale topography reads the same "
        "files; needs the extra brdfscale[topography])",
    )
    add_reading_options(parser)
    parser.add_argument("--out", required=True, help="output .exr file")
    parser.add_argument(
        "--scales",
        type=scales,
        default=None,
        metavar="SCALES",
        help="facet sizes μ, comma-separated, each a whole number of pixels: for SURFACE pixel counts "
        "from 1 to --size (4,16,64, the default, or 4px,16px,64px); for --topography lengths with a "
        "unit (0.5um, 1e-6m, 0.1mm) or pixel counts (4px); or auto[:COUNT] (COUNT log-spaced pixel "
        "counts up to half the field; the default for --topography is auto:8)",
    )
    parser.add_argument(
        "--incident",
        type=_incident,
        action="append",
        metavar="THETA[:PHI]",
        help="incident direction in degrees; repeat for several (default 0)",
    )
    parser.add_argument(
        "--noise",
        type=_noise,
        default=None,
        metavar="MODEL",
        help="none, poisson:EXPOSURE[:READ_NOISE] (counts per unit lobe value; optional Gaussian "
        "read noise in counts, which makes σ exact in dark pixels) or gaussian:SIGMA; default none for SURFACE, "
        f"{TOPOGRAPHY_NOISE} for --topography (σ stored in every image, so brdfscale fit runs on the file)",
    )
    parser.add_argument(
        "--resolution",
        type=real(0.0, 10.0),
        default=None,
        help="instrument blur, slope std, 0–10; default 0 for SURFACE, for --topography "
        f"{TOPOGRAPHY_RESOLUTION:g} image pixels (2·extent/(pixels − 1) each): an instrument resolves no finer "
        "than its pixels, and the finest scale's lobe of mirror pixel facets is then a resolved spot, not one pixel; "
        "or the file's slope quantum (height step / pitch) where its heights are quantised and that is larger: "
        "its lobes are otherwise combs of spikes one quantum apart",
    )
    parser.add_argument(
        "--micro-alpha",
        type=real(0.0, 10.0, strict_lo=True),
        default=None,
        metavar="ALPHA",
        help="Beckmann roughness of the pixel facets, in (0, 10] (default: mirror facets)",
    )
    parser.add_argument(
        "--extent",
        type=real(0.0, 1000.0, strict_lo=True),
        default=None,
        help="image half-width in slope units, in (0, 1000] (default: 1.5 × the 99th percentile of the pixel "
        "slopes' deviation |m − m̄| from their mean — robust to outlier pixels, brdfscale.synth.robust_extent)",
    )
    parser.add_argument("--pixels", type=integer(3, 1025), default=65, help="image nodes per axis, 3–1025 (default 65)")
    parser.add_argument(
        "--size",
        type=integer(16, 4096),
        default=None,
        help=f"height field pixels per side of SURFACE, 16–4096 (default {_SIZE}; not with --topography)",
    )
    parser.add_argument(
        "--seed",
        type=seed,
        default=None,
        help=f"random seed of surface and noise, 0–{MAX_SEED} (default {_SEED}; with --topography it "
        "seeds the noise, so it needs --noise)",
    )
    parser.add_argument(
        "--weighting",
        choices=WEIGHTINGS.names,
        default=None,
        help=f"pixel-facet weighting of --instrument facets — {WEIGHTINGS.help()}",
    )
    parser.add_argument(
        "--instrument",
        choices=INSTRUMENTS.names,
        default=INSTRUMENTS.default,
        help=f"the instrument — {INSTRUMENTS.help()}",
    )
    parser.add_argument(
        "--rays",
        type=integer(1, 10**10),
        default=None,
        metavar="N",
        help="with --instrument raytraced: rays per measurement configuration (default: brdfscale.instrument's)",
    )
    parser.add_argument(
        "--bounces",
        type=integer(1, 64),
        default=None,
        metavar="N",
        help="with --instrument raytraced: the most reflections a path may take, 1 (single scattering) to 64 "
        "(default: brdfscale.instrument's)",
    )
    parser.add_argument(
        "--micro",
        choices=MICRO_FACETS.names,
        default=None,
        help=f"with --instrument raytraced and --micro-alpha: the pixel facets' microfacet distribution — "
        f"{MICRO_FACETS.help()}",
    )
    parser.add_argument(
        "--variant",
        default=None,
        metavar="NAME",
        help="with --instrument raytraced: Mitsuba's variant (llvm_ad_rgb, scalar_rgb, cuda_ad_rgb; default: the "
        "first of these that runs here)",
    )
    parser.add_argument(
        "--workers",
        type=integer(1, 4096),
        default=None,
        help="with --instrument raytraced: trace the images as tasks on a local Ray instance with this many CPUs "
        "(the same file as in this process; needs brdfscale[cluster])",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="with --instrument raytraced: trace the images as tasks on the Ray cluster at this address (e.g. auto, "
        "or HOST:6379; the same file as in this process; needs brdfscale[cluster])",
    )
    parser.add_argument(
        "--dtype", choices=("float32", "float16"), default="float32", help="pixel type (default float32)"
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing output file")
    parser.set_defaults(func=run)


def _check_source(args) -> None:
    """Exactly one of SURFACE and --topography, and only the options that apply to it."""
    if (args.surface is None) == (args.topography is None):
        raise InvalidInputError("give either a built-in SURFACE or --topography FILE (exactly one of the two).")
    if args.topography is None:
        given = [
            flag for flag, value in (("--channel", args.channel), ("--detrend", args.detrend)) if value is not None
        ]
        if given:
            raise InvalidInputError(
                f"{' and '.join(given)}: how a topography file is read; give "
                f"{'them' if len(given) > 1 else 'it'} with --topography only."
            )
        return
    if args.size is not None:
        raise InvalidInputError(
            "--size sets the size of a built-in SURFACE; a topography has its own "
            "(brdfscale topography FILE prints it): leave --size out with --topography."
        )
    if args.seed is not None and args.noise == "none":
        raise InvalidInputError(
            "--seed: a topography is not random, so with --topography the seed only seeds the "
            "noise; leave --noise none out, or leave --seed out."
        )


def _check_instrument(args) -> None:
    """The options of the other instrument refused, by name."""
    raytraced = args.instrument == "raytraced"
    names = _FACETS_ONLY if raytraced else _RAYTRACED_ONLY
    given = [flag for flag in names if getattr(args, flag[2:]) is not None]
    if given:
        what = "--instrument facets" if raytraced else "--instrument raytraced"
        raise InvalidInputError(
            f"{' and '.join(given)}: {'options' if len(given) > 1 else 'an option'} of {what} only; leave "
            f"{'them' if len(given) > 1 else 'it'} out with --instrument {args.instrument}"
            + (
                " (the ray tracer's σ is its Monte Carlo error; its resolution is its detector's)."
                if raytraced
                else "."
            )
        )
    if args.micro is not None and args.micro_alpha is None:
        raise InvalidInputError("--micro names the pixel facets' distribution of roughness --micro-alpha: give both.")


def run(args) -> int:
    import numpy as np

    from .. import stats, synth

    _check_source(args)
    _check_instrument(args)
    output_file(args.out, args.force)
    raytraced = args.instrument == "raytraced"
    if raytraced:  # a missing Mitsuba or LLVM named in one line before any work (exit status 2)
        from .. import _mitsuba

        _mitsuba.mitsuba(args.variant)
    seed_value = _SEED if args.seed is None else args.seed
    surface_seed, noise_seed = np.random.SeedSequence(seed_value).spawn(2)
    micro_kind = {"beckmann": stats.Beckmann, "ggx": stats.GGX}[args.micro or MICRO_FACETS.default]
    micro = None if args.micro_alpha is None else micro_kind(args.micro_alpha)
    if args.topography is None:
        size = _SIZE if args.size is None else args.size
        chosen = args.scales if args.scales is not None else scales("4,16,64")
        pixels = chosen.pixels()
        if pixels is not None and max(pixels) > size:
            raise InvalidInputError(
                f"--scales {max(pixels):g} exceeds the field's --size {size}: a facet cannot "
                "be larger than the surface."
            )
        field = synth.named_surface(args.surface, size=size, seed=np.random.default_rng(surface_seed), micro=micro)
        field = synth.HeightField(
            field.heights,
            field.spacing,
            micro=field.micro,
            spectrum=field.spectrum,
            description={**field.description, "seed": seed_value},
        )
        source, command = f"{args.surface}, {size}² field", f"brdfscale synth {args.surface}"
    else:
        chosen = args.scales if args.scales is not None else scales("auto:8")
        field = read_field(args.topography, args, micro=micro)
        (ny, nx) = field.shape
        source = f"{field.description.get('file', args.topography)}, {ny} × {nx} measured field"
        command = f"brdfscale synth --topography {args.topography} {reading_command(args)} --scales {chosen}"
    mus = chosen.resolve(field)
    if chosen.auto is not None and len(mus) < min(chosen.auto, MIN_FIT_SCALES):  # fewer than a fit needs and
        (ny, nx) = field.shape  # than asked for; a single scale asked for (by name or auto:1) is made
        given = "" if args.scales is not None else " (the default)"
        larger = "measure a larger field" if args.topography is not None else "give a larger --size"
        admitted = ", ".join(f"{mu:g}" for mu in mus)
        raise InvalidInputError(
            f"--scales {chosen.text}{given}: this {ny} × {nx} field admits {len(mus)} facet scale"
            f"{'s' if len(mus) != 1 else ''} (μ = {admitted} {field.unit or 'px'}); brdfscale fit needs "
            f"{MIN_FIT_SCALES} or more: give --scales {MIN_FIT_SCALES} sizes the field holds (e.g. 1px,2px), or "
            f"{larger}."
        )
    topography = args.topography is not None
    extent = args.extent if args.extent is not None else synth.robust_extent(field)
    incident = np.array(args.incident) if args.incident else np.array([[0.0, 0.0, 1.0]])
    if raytraced:
        return _raytraced(args, field, mus, incident, extent, seed_value, noise_seed, command, source)
    noise = args.noise if args.noise is not None else _noise(TOPOGRAPHY_NOISE) if topography else "none"
    noise = None if noise == "none" else noise
    resolution, resolution_text = args.resolution, None
    if resolution is None:
        resolution, resolution_text = default_resolution(field, extent, args.pixels) if topography else (0.0, "0")
    defaults = {
        "extent": None
        if args.extent is not None
        else f"robust_extent: 1.5 × the 99th percentile of the pixel slopes' |m − m̄|: {extent:.6g}",
        "noise": None if args.noise is not None else (TOPOGRAPHY_NOISE if topography else "none"),
        "resolution": resolution_text,
    }
    mset = synth.gonioreflectometer(
        field,
        mus,
        incident,
        extent=extent,
        pixels=args.pixels,
        noise=noise,
        resolution=resolution,
        weighting=args.weighting or WEIGHTINGS.default,
        seed=np.random.default_rng(noise_seed) if noise is not None else None,
    )
    mset.metadata["seed"] = seed_value
    mset.metadata["command"] = command
    mset.metadata["defaults"] = {k: v for k, v in defaults.items() if v is not None}  # the options left out
    return _write(args, mset, field, mus, source)


def _write(args, mset, field, mus, source) -> int:
    from .. import exr, topography

    if args.topography is not None:  # the few pixel slopes that can carry Σ: fit's ΔΣ-truth table says so
        mset.metadata.setdefault("truth", {})["slope_outliers"] = topography.slope_outliers(field).to_json()

    exr.write_measurements(args.out, mset, overwrite=args.force, dtype=args.dtype)
    shown = ", ".join(f"{mu:.6g}" for mu in mus) + ("" if field.unit is None else f" {field.unit}")
    print(f"wrote {args.out}: {len(mset.images)} lobe images ({source}, scales {shown})")
    return 0


def _raytraced(args, field, mus, incident, extent, seed_value, trace_seed, command, source) -> int:
    """The measurement by the ray tracer: :func:`brdfscale.instrument.measure` with the options given (its own
    defaults for the others, recorded by it in the file's provenance)."""
    from .. import instrument

    given = {name: getattr(args, name) for name in ("rays", "bounces", "variant") if getattr(args, name) is not None}
    mset = instrument.measure(
        field,
        mus,
        incident,
        extent=extent,
        pixels=args.pixels,
        micro=field.micro,
        seed=int(trace_seed.generate_state(1)[0]),
        workers=args.workers,
        address=args.address,
        **given,
    )
    mset.metadata["seed"] = seed_value
    mset.metadata["command"] = f"{command} --instrument raytraced" + "".join(
        f" --{name} {value}" for name, value in given.items()
    )
    if args.extent is None:
        mset.metadata["defaults"] = {
            "extent": f"robust_extent: 1.5 × the 99th percentile of the pixel slopes' |m − m̄|: {extent:.6g}"
        }
    return _write(args, mset, field, mus, source)
