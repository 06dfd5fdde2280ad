"""``brdfscale fit-library DIR_OR_FILES... --out DIR``: a library of measurement sets, fitted in
batches (:func:`brdfscale.library.fit_library`), in this process or on Ray."""

import os

from .._errors import InvalidInputError
from . import EXIT_OK, EXIT_SOME_FAILED
from ._fit import (
    add_fit_options,
    check_fit_options,
    check_sampler_options,
    load_fitting,
    spec_of,
)
from ._options import integer, output_directory, real


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "fit-library",
        help="fit many measurement sets (a material library) in batches, in-process or on a Ray cluster",
        description="Fit every measurement set (*.exr) among the given files and directories with the same model "
        "and options: batches of materials fitted together (one compiled program per bucket of a batch, divided "
        "over the devices), in this process or as Ray tasks (--workers N: a local Ray instance; --address: a cluster). "
        "Writes DIR/library.json (the index: status, χ²/dof, errors) and DIR/materials/NAME/ (each material's "
        "report). Interrupted, it resumes: a rerun fits only the materials whose report is not there and whole "
        "(a damaged one is fitted again, and said); a local Ray instance it started stops with it, even after kill -9. "
        "docs/library.md",
    )
    parser.add_argument(
        "sources",
        nargs="+",
        metavar="DIR_OR_FILES",
        help="measurement files, or directories searched recursively for *.exr",
    )
    add_fit_options(parser)
    parser.set_defaults(steps=0)
    parser.add_argument(
        "--default-sigma",
        type=real(0.0, 1e30, strict_lo=True),
        default=None,
        help="noise σ > 0 for images without a sigma channel (lobe units)",
    )
    parser.add_argument(
        "--batch", type=integer(1, 4096), default=16, help="materials per task, fitted together, 1–4096 (default 16)"
    )
    parser.add_argument(
        "--address",
        default=None,
        help="connect to the Ray cluster at this address (e.g. auto, or HOST:6379); needs brdfscale[cluster]",
    )
    parser.add_argument(
        "--workers",
        type=integer(1, 4096),
        default=None,
        help="run on a local Ray instance with this many CPUs (one task per CPU); needs brdfscale[cluster]",
    )
    parser.add_argument(
        "--cpus-per-task",
        type=real(0.0, 4096.0, strict_lo=True),
        default=1.0,
        help="CPUs Ray reserves for each task (default 1)",
    )
    parser.add_argument(
        "--figures",
        action="store_true",
        help="also write each material's three report figures (PNG; on a CPU they take longer than the fit)",
    )
    parser.set_defaults(func=run)
    for action in parser._actions:  # the library's own wording of the shared options
        if action.dest == "steps":
            action.help = (
                "draws per chain of each material's posterior sampling after its fit (default 0: Laplace "
                "uncertainties only, as FitSpec(sampler=None); --sampler chooses the sampler)"
            )
        elif action.dest == "force":
            action.help = "refit every material (also when DIR holds a library fitted with other options)"


def run(args) -> int:
    from .. import library

    check_fit_options(args)
    on_ray = bool(args.address or args.workers)
    # in-process batches need float64 in this process; Ray tasks set it themselves, and a driver
    # that only schedules them need not import the fitting stack (seconds of start-up)
    if not on_ray:
        load_fitting()
    if args.steps > 0 and args.model == "parametric":
        check_sampler_options(
            args,
            len(load_fitting().ParametricModel(args.family, args.family, law=args.law, fixed=dict(args.fix)).names),
        )
    if args.walkers is not None:
        raise InvalidInputError(
            "--walkers is not available for libraries: emcee runs max(32, 4 × parameters) walkers per ensemble there."
        )
    output_directory(args.out)
    spec = spec_of(args)
    materials = library.find_materials(args.sources)
    where = (
        f"the Ray cluster at {args.address}"
        if args.address
        else f"a local Ray instance with {args.workers} CPU(s)"
        if args.workers
        else "this process"
    )
    print(f"{len(materials)} materials → {args.out}, batches of {args.batch}, on {where}")
    result = library.fit_library(
        args.sources,
        args.out,
        spec=spec,
        batch=args.batch,
        address=args.address,
        workers=args.workers,
        cpus_per_task=args.cpus_per_task,
        force=args.force,
        progress=not args.no_progress,
        stream=print,
    )
    print(result.table())
    print(f"wrote {os.path.join(result.out, library.INDEX)}")
    return EXIT_OK if not result.failures else EXIT_SOME_FAILED
