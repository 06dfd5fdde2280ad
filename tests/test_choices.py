"""One source for every name and default (brdfscale.choices): the command line, the library's
FitSpec and fitting's signatures agree with the table; every name in it is accepted by each;
the table and the command's parser import without JAX; library messages name Python
arguments, and the command translates them to its flags."""

import ast
import dataclasses
import inspect
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest

from brdfscale import choices, fitting, InvalidInputError, library, lobes, stats
from brdfscale._cli import build_parser, FLAGS, in_flags


ROOT = pathlib.Path(__file__).resolve().parents[1]


def _parsed(command: str, *extra: str):
    argv = {"fit": ["fit", "m.exr", "--out", "d"], "fit-library": ["fit-library", "lib", "--out", "d"]}[command]
    return build_parser().parse_args([*argv, *extra])


def _defaults(function) -> dict:
    return {
        name: p.default
        for name, p in inspect.signature(function).parameters.items()
        if p.default is not inspect.Parameter.empty
    }


def test_the_table_and_the_command_line_parser_import_without_jax():
    code = (
        "import sys; from brdfscale import choices; from brdfscale._cli import build_parser; build_parser(); "
        "assert choices.SAMPLERS.default in choices.SAMPLERS; "
        "print(sorted(m for m in ('jax', 'jaxlib', 'brdfscale.fitting') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT, check=False
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_command_line_defaults_equal_the_library_defaults():
    """Every option the command shares with fitting and FitSpec has the same default there, read
    from the parser and from the functions' signatures."""
    args = _parsed("fit")
    fit, fit_many, sample, sample_many = (
        _defaults(f) for f in (fitting.fit, fitting.fit_many, fitting.sample, fitting.sample_many)
    )
    spec = {f.name: f.default for f in dataclasses.fields(library.FitSpec)}
    for option in ("solver", "starts", "max_steps", "seed"):
        assert (
            getattr(args, option) == fit[option] == fit_many[option] == spec[option] == getattr(choices.FIT, option)
        ), option
    for option in ("sampler", "chains", "steps", "seed"):
        assert getattr(args, option) == sample[option] == getattr(choices.SAMPLE, option), option
        if option != "sampler":
            assert sample_many[option] == sample[option], option
    # sample_many runs one program over many materials: a gradient sampler, not auto's per-posterior choice
    assert sample_many["sampler"] == choices.SAMPLE.batched_sampler == "nuts" != choices.SAMPLE.sampler == "auto"
    for option in ("chains", "steps"):
        assert spec[option] == getattr(choices.SAMPLE, option), option
    assert spec["sampler"] is None  # a library samples only when asked; then --steps > 0 passes --sampler's default
    for option in ("model", "family", "law", "base_nodes", "knots", "regularisation"):
        assert getattr(args, option) == spec[option] == getattr(choices.MODEL, option), option
    parametric = _defaults(fitting.ParametricModel.__init__)
    assert parametric["lobe"] == parametric["statistics"] == args.family and parametric["law"] == args.law
    nonparametric = _defaults(fitting.NonParametricModel.__init__)
    assert (nonparametric["base_nodes"], nonparametric["n_knots"], nonparametric["regularisation"]) == (
        args.base_nodes,
        args.knots,
        args.regularisation,
    )
    # fit-library: the same, but no sampling unless --steps is given (FitSpec's sampler None)
    lib = _parsed("fit-library")
    for option in ("solver", "starts", "max_steps", "seed", "model", "family", "law", "chains", "increments"):
        assert getattr(lib, option) == getattr(args, option), option
    assert lib.steps == 0 and lib.sampler == choices.SAMPLE.sampler


def test_the_help_states_the_defaults_the_parser_uses(capsys):
    """``brdfscale fit --help`` says each default, and names the default sampler (auto), not emcee."""
    with pytest.raises(SystemExit):
        build_parser().parse_args(["fit", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for flag in ("--starts", "--max-steps", "--chains", "--steps", "--seed", "--base-nodes", "--knots"):
        value = getattr(_parsed("fit"), flag[2:].replace("-", "_"))
        section = text.split(f"{flag} {flag[2:].replace('-', '_').upper()} ", 1)[1]
        said = f"default {value}" if value is not None else f"default: {choices.SAMPLE.steps_text()}"
        assert section.split(" --", 1)[0].count(said) == 1, flag
    for flag, table in (
        ("--solver", choices.SOLVERS),
        ("--sampler", choices.SAMPLERS),
        ("--model", choices.MODELS),
        ("--family", choices.FAMILIES),
        ("--law", choices.LAWS),
        ("--shape", choices.SHAPES),
        ("--increments", choices.INCREMENTS),
    ):
        assert f"{table.default} (default): {table.summary(table.default)}" in text, flag
    said = f"(optimistix, then the sampler --sampler names, by default auto: {choices.SAMPLERS.summary('auto')}; "
    assert said in text and "optimistix + emcee" not in text


@pytest.mark.parametrize(
    "table,option",
    [
        (choices.SOLVERS, "solver"),
        (choices.SAMPLERS, "sampler"),
        (choices.MODELS, "model"),
        (choices.FAMILIES, "family"),
        (choices.LAWS, "law"),
        (choices.SHAPES, "shape"),
        (choices.INCREMENTS, "increments"),
    ],
)
def test_every_name_in_the_table_is_accepted_by_the_command_and_the_library(table, option):
    for name in table:
        assert getattr(_parsed("fit", f"--{option}", name), option) == name
        assert getattr(library.FitSpec(**{option: name}), option) == name
    with pytest.raises(SystemExit):
        _parsed("fit", f"--{option}", "no-such-name")
    with pytest.raises(InvalidInputError, match=f"{option} must be"):
        library.FitSpec(**{option: "no-such-name"})


def test_every_name_in_the_table_is_accepted_by_fitting():
    assert tuple(fitting.SOLVERS) == choices.SOLVERS.names
    assert set(fitting.SAMPLERS) == set(choices.SAMPLERS.names)
    for name in choices.SAMPLERS:
        assert fitting.SAMPLERS[name]().name == name
    for family in choices.FAMILIES:
        for law in choices.LAWS:
            if law == "spline":  # the table says: anisotropic_law only
                with pytest.raises(InvalidInputError, match="law must be one of"):
                    fitting.ParametricModel(family, family, law=law)
                assert fitting.AnisotropicLawModel(law, scales=[1.0, 2.0]).names
            elif law == "gaussian_surface" and family != "beckmann":  # the table says: Beckmann only
                with pytest.raises(Exception, match="gaussian_surface"):
                    fitting.ParametricModel(family, family, law=law)
            else:
                assert fitting.ParametricModel(family, family, law=law).names
    classes = {
        "parametric": fitting.ParametricModel,
        "nonparametric": fitting.NonParametricModel,
        "anisotropic": fitting.AnisotropicModel,
        "isotropic": fitting.AnisotropicModel,
        "anisotropic_law": fitting.AnisotropicLawModel,
        "nonparametric_anisotropic": fitting.AnisotropicNonParametricModel,
    }
    assert classes.keys() == set(choices.MODELS)
    assert all(library.model_class(name) is cls for name, cls in classes.items())  # the one name → class table
    for shape in choices.SHAPES:
        assert fitting.AnisotropicModel(2, shape=shape).shape == shape
    for increments in choices.INCREMENTS:
        assert fitting.AnisotropicModel(2, increments=increments).increments == increments
        assert fitting.AnisotropicLawModel(increments=increments).increments == increments


def test_the_table_refuses_unknown_names_naming_the_argument():
    assert choices.SAMPLERS.check("hmc") == "hmc"
    said = "sampler must be one of 'nuts', 'hmc', 'emcee', 'imh', 'auto'; got 'gibbs'"
    with pytest.raises(InvalidInputError, match=said):
        choices.SAMPLERS.check("gibbs")
    assert len(choices.SOLVERS) == len(set(choices.SOLVERS.names)) == 7


def test_every_flag_the_translation_names_exists():
    parser = build_parser()
    flags = {s for sub in parser.subcommands.values() for a in sub._actions for s in a.option_strings}
    for phrase, flag in FLAGS.items():
        assert flag.rstrip(":") in flags, phrase


def test_library_messages_in_the_command_s_words():
    assert (
        in_flags("m.exr: file exists; pass overwrite=True to replace it.")
        == "m.exr: file exists; pass --force to replace it."
    )
    assert in_flags("fixed: fixed alpha_lobe = 1e-30 lies outside") == "--fix: fixed alpha_lobe = 1e-30 lies outside"
    assert (
        in_flags("pass default_sigma= (σ) or store a 'sigma' channel; timeout=3, fixed: no")
        == "pass --default-sigma (σ) or store a 'sigma' channel; timeout=3, fixed: no"
    )
    assert in_flags("choose another out_dir= or pass overwrite=True") == "choose another --out or pass --force"


def _raised_texts(path: pathlib.Path):
    """The string literals of every ``raise`` statement of a module (f-strings' literal parts too)."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Raise) and node.exc is not None:
            for inner in ast.walk(node.exc):
                if isinstance(inner, ast.Constant) and isinstance(inner.value, str):
                    yield node.lineno, inner.value


def test_library_messages_name_python_arguments_not_flags():
    """Outside the command (brdfscale/_cli), no error message names a command-line flag: a Python
    user is told the argument (``overwrite=True``), and the command translates it (:data:`FLAGS`)."""
    flag = re.compile(r"(?<![\w-])--[a-z][a-z-]+")
    found = []
    for path in sorted([*(ROOT / "brdfscale").rglob("*.py"), *(ROOT / "fitting").rglob("*.py")]):
        if "_cli" in path.parts:
            continue
        found += [
            f"{path.relative_to(ROOT)}:{line}: {text!r}" for line, text in _raised_texts(path) if flag.search(text)
        ]
    assert not found, "\n".join(found)


def test_the_instrument_and_render_names_are_the_table_s_and_each_is_accepted():
    """brdfscale synth --instrument, the ray-traced instrument's binnings, meshes and executors, and render's forms,
    outputs and footprints: the names the modules accept are the table's (one place), the instrument's public names
    are the same objects, and an unknown name is refused by the library's own exception naming the argument."""
    from brdfscale import _cluster, instrument, synth
    from brdfscale.render import _integrator, _material

    parser = build_parser()
    assert instrument.BINNINGS is choices.BINNINGS and instrument.SURFACES is choices.MESHES
    for name in choices.INSTRUMENTS:
        assert parser.parse_args(["synth", "gaussian", "--out", "m.exr", "--instrument", name]).instrument == name
    assert parser.parse_args(["synth", "gaussian", "--out", "m.exr"]).instrument == choices.INSTRUMENTS.default
    field = synth.HeightField(np.zeros((8, 8)), 1.0, periodic=True)
    for binning in choices.BINNINGS:
        for surface in choices.MESHES:
            plan = instrument.Measurement(field, [2.0], [0.0, 0.0, 1.0], extent=0.5, binning=binning, surface=surface)
            assert (plan.binning, plan.surface) == (binning, surface)
    assert {_cluster.resolve_executor(name, None, None) for name in choices.EXECUTORS} == {"process", "ray"}
    gaussian = [lobes.Lobe(stats.Gaussian(sigma=0.1))]  # an evolved Gaussian lobe: the closed form applies
    assert [_material.choose_form(name, gaussian).name for name in choices.FORMS] == [
        "closed",
        "table",
        "closed",
        "spline",
    ]
    for output in choices.OUTPUTS:
        for footprint in choices.FOOTPRINTS:
            assert _integrator.check_options(2, output, footprint) == (2, output, footprint)
    for table, refuse in (
        (choices.BINNINGS, lambda: instrument.Measurement(field, [2.0], [0, 0, 1.0], extent=0.5, binning="cic")),
        (choices.MESHES, lambda: instrument.Measurement(field, [2.0], [0, 0, 1.0], extent=0.5, surface="smooth")),
        (choices.EXECUTORS, lambda: _cluster.resolve_executor("cluster", None, None)),
        (choices.FORMS, lambda: _material.choose_form("cubic", gaussian)),
        (choices.OUTPUTS, lambda: _integrator.check_options(2, "depth", "pixel")),
        (choices.FOOTPRINTS, lambda: _integrator.check_options(2, "radiance", "texel")),
    ):
        with pytest.raises(InvalidInputError, match=f"{table.what} must be one of {', '.join(map(repr, table))}; got"):
            refuse()
    with pytest.raises(SystemExit):
        parser.parse_args(["synth", "gaussian", "--out", "m.exr", "--instrument", "camera"])
    for flag, table in (("--weighting", choices.WEIGHTINGS), ("--micro", choices.MICRO_FACETS)):
        for name in table:
            assert getattr(parser.parse_args(["synth", "gaussian", "--out", "m.exr", flag, name]), flag[2:]) == name
        with pytest.raises(SystemExit):
            parser.parse_args(["synth", "gaussian", "--out", "m.exr", flag, "no-such-name"])


def test_the_facet_instrument_refuses_an_unknown_weighting_with_the_table_s_message():
    from brdfscale import synth

    field = synth.HeightField(np.zeros((8, 8)), 1.0, periodic=True)
    with pytest.raises(InvalidInputError, match="weighting must be one of 'nearly_flat', 'projected_area'; got 'x'"):
        synth.gonioreflectometer(field, [2.0], [0.0, 0.0, 1.0], extent=0.5, weighting="x")


def test_the_public_module_names_every_table_and_default():
    """brdfscale.choices's __all__ (the one list of the public names) holds every Choices table, every defaults
    class and instance and every upper-case integer constant (MIN_FIT_SCALES) of brdfscale._choices, and nothing
    it does not define."""
    from brdfscale import _choices

    classes = {value for value in vars(_choices).values() if isinstance(value, type)}
    ours = {cls for cls in classes if cls.__module__ == _choices.__name__}  # Choice, Choices, the defaults classes
    defined = {
        name
        for name, value in vars(_choices).items()
        if not name.startswith("_")
        and (value in ours or isinstance(value, tuple(ours)) or (name.isupper() and type(value) is int))
    }
    assert set(choices.__all__) == defined and len(choices.__all__) == len(defined)
    assert all(getattr(choices, name) is getattr(_choices, name) for name in defined)


def test_starts_is_auto_or_a_count():
    """``--starts`` takes ``auto`` (the default: the model's own count, fitting.resolve_starts) or 1–256."""
    assert _parsed("fit").starts == choices.FIT.starts == "auto"
    assert _parsed("fit", "--starts", "3").starts == 3
    for bad in ("0", "257", "many"):
        with pytest.raises(SystemExit):
            _parsed("fit", "--starts", bad)
