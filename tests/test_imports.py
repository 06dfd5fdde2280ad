"""Import hygiene: importing brdfscale or brdfscale.fitting changes no global state, loads
JAX and matplotlib only when used, and the command line starts without JAX where it needs none.

Each check runs in a fresh interpreter (this test process has imported everything already).
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest


def _run(code: str, cwd=None) -> dict:
    """Run ``code`` in a fresh interpreter; it prints one JSON line, returned parsed."""
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_ENABLE_X64", "MPLBACKEND")}
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=cwd, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_import_changes_no_global_state_and_is_lazy():
    got = _run("""
        import json, sys
        import brdfscale
        after_brdfscale = sorted(m for m in ("jax", "matplotlib", "numpy", "scipy", "equinox") if m in sys.modules)
        import brdfscale.exr, brdfscale.fitting, brdfscale.stats, brdfscale.plot, brdfscale.show
        from brdfscale import lobes, stats
        repr(lobes.Beckmann(0.1)); repr(stats.GGX(0.2))  # showing objects needs no matplotlib either
        import jax
        print(json.dumps({"after_brdfscale": after_brdfscale, "x64": bool(jax.config.jax_enable_x64),
                          "matplotlib": "matplotlib" in sys.modules, "evolve": callable(brdfscale.evolve),
                          "dir": "MeasurementSet" in dir(brdfscale)}))
    """)
    assert got["after_brdfscale"] == []  # only the exception classes are loaded by `import brdfscale`
    assert got["x64"] is False
    assert got["matplotlib"] is False
    assert got["evolve"] and got["dir"]


def _third_party_imports() -> list[str]:
    """The modules outside brdfscale that its modules import at module level (not inside functions)."""
    import ast
    from pathlib import Path

    import brdfscale

    root = Path(brdfscale.__file__).parent
    names = set()
    for path in [*root.rglob("*.py"), *(root.parent / "fitting").rglob("*.py")]:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        body = [*tree.body, *(n for node in tree.body if isinstance(node, (ast.If, ast.Try)) for n in ast.walk(node))]
        for node in body:
            if isinstance(node, ast.Import):
                names.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module)
    return sorted(n for n in names if n.split(".")[0] not in ("brdfscale", "fitting", "__future__"))


def test_importing_every_public_module_changes_no_global_state():
    """A notebook's state is the same before and after importing every public module of brdfscale
    (brdfscale.instrument and brdfscale.render included) and every public name: JAX's configuration,
    matplotlib's settings (no backend picked, pyplot not loaded), warnings filters, logging's loggers,
    the environment, NumPy's print and error settings, the SIGINT handler and the excepthook; Mitsuba
    and Dr.Jit are not even loaded (so no variant is selected). The third-party modules brdfscale
    imports at module level are imported before the first snapshot: what they do on import is theirs."""
    got = _run(f"""
        import importlib, json, logging, os, signal, sys, warnings
        for name in {_third_party_imports()!r}:
            if name.split(".")[0] not in ("mitsuba", "drjit"):
                try:
                    importlib.import_module(name)
                except ImportError:  # an optional extra that is not installed
                    pass
        import jax, matplotlib, numpy as np

        def state():
            loggers = {{name: [lg.level, [type(h).__name__ for h in lg.handlers], lg.propagate, lg.disabled]
                       for name, lg in [("", logging.getLogger()), *logging.Logger.manager.loggerDict.items()]
                       if isinstance(lg, logging.Logger) and (lg.handlers or lg.level or name == "")}}
            return {{"jax": {{k: repr(v) for k, v in jax.config.values.items()}},
                    "matplotlib": {{k: repr(dict.__getitem__(matplotlib.rcParams, k)) for k in matplotlib.rcParams}},
                    "pyplot": "matplotlib.pyplot" in sys.modules, "warnings": [repr(f) for f in warnings.filters],
                    "showwarning": repr(warnings.showwarning), "loggers": loggers,
                    "logging.disable": logging.root.manager.disable, "environ": dict(os.environ),
                    "numpy": [repr(np.get_printoptions()), repr(np.geterr())],
                    "sigint": repr(signal.getsignal(signal.SIGINT)), "excepthook": repr(sys.excepthook)}}

        before = state()
        import brdfscale
        modules = ["choices", *(n for n, where in brdfscale._LAZY.items() if where == "." + n)]
        for name in modules:
            importlib.import_module("brdfscale." + name)
        for name in brdfscale.__all__:
            getattr(brdfscale, name)
        after = state()
        changed = {{k: [before[k], after[k]] for k in before if before[k] != after[k]}}
        print(json.dumps({{"changed": changed, "modules": modules,
                          "mitsuba": [m for m in ("mitsuba", "drjit") if m in sys.modules]}}))
    """)
    assert {"instrument", "render", "fitting", "plot", "library"} <= set(got["modules"])
    assert got["changed"] == {}
    assert got["mitsuba"] == []


def test_importing_instrument_and_render_keeps_the_users_mitsuba_variant():
    """A user who picked a Mitsuba variant before importing brdfscale keeps it: the variant is
    process-wide and only a call that needs the ray tracer asks brdfscale._mitsuba for one."""
    pytest.importorskip("mitsuba")
    got = _run("""
        import json
        import mitsuba as mi
        mi.set_variant("scalar_rgb")
        import brdfscale.instrument, brdfscale.render
        from brdfscale.render import bsdf, export_roughness, register
        print(json.dumps({"variant": mi.variant()}))
    """)
    assert got == {"variant": "scalar_rgb"}


def test_fitting_in_float32_mode_says_which_line_to_add():
    got = _run("""
        import json
        import numpy as np
        import brdfscale
        from brdfscale import LobeImage, MeasurementSet, fitting
        m = MeasurementSet(tuple(LobeImage(mu=mu, incident=np.array([0., 0., 1.]), extent=0.5, values=np.ones((8, 8)),
                                           sigma=np.ones((8, 8))) for mu in (1.0, 2.0)))
        try:
            fitting.Dataset.from_measurements(m)
        except brdfscale.InvalidInputError as err:
            print(json.dumps({"message": str(err)}))
    """)
    assert 'jax.config.update("jax_enable_x64", True)' in got["message"]


def test_unknown_attribute_is_an_attribute_error():
    import brdfscale

    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        brdfscale.nonexistent  # noqa: B018


def test_brdfscale_fitting_is_the_fitting_folder_and_no_top_level_fitting_is_installed(tmp_path):
    """The repository's ``fitting/`` folder is installed as ``brdfscale.fitting`` (pyproject's
    package-dir): outside the checkout there is no module named ``fitting`` at all."""
    import brdfscale
    from brdfscale import fitting

    assert brdfscale.fitting is fitting and sys.modules["brdfscale.fitting"] is fitting
    assert fitting.__name__ == "brdfscale.fitting" and fitting.fit.__module__.startswith("brdfscale.fitting.")
    got = _run(
        """
        import importlib.util, json
        print(json.dumps({"fitting": importlib.util.find_spec("fitting") is not None}))
    """,
        cwd=tmp_path,
    )
    assert got == {"fitting": False}


@pytest.mark.slow  # two fresh interpreters (≈ 9 s): the default suite's 6-minute budget
def test_a_local_fitting_py_cannot_shadow_brdfscale_fitting(tmp_path):
    """A file or folder named ``fitting`` in the working directory is another module: it cannot
    take brdfscale.fitting's place, whether imported before or not at all."""
    (tmp_path / "fitting.py").write_text("x = 1\n")
    (tmp_path / "brdfscale_fitting_probe.py").write_text("")
    code = """
        import json, sys
        from brdfscale import fitting
        local = sys.modules.get("fitting")
        print(json.dumps({"name": fitting.__name__, "fit": callable(fitting.fit),
                          "local": getattr(local, "x", None)}))
    """
    got = _run(code, cwd=tmp_path)  # `python -c` puts the working directory first on sys.path
    assert got == {"name": "brdfscale.fitting", "fit": True, "local": None}
    got = _run("import fitting\n" + textwrap.dedent(code), cwd=tmp_path)  # the local file imported first
    assert got == {"name": "brdfscale.fitting", "fit": True, "local": 1}


def test_the_lazy_table_lists_every_public_name_once_and_each_imports():
    """brdfscale's public names come from one table (``_TABLE``): each listed once, each loads,
    ``__all__`` is the table, and the TYPE_CHECKING imports (for type checkers) say the same."""
    import ast
    import importlib
    from pathlib import Path

    import brdfscale

    names = [name for _, group in brdfscale._TABLE for name in group]
    assert len(names) == len(set(names)), sorted(n for n in names if names.count(n) > 1)
    assert brdfscale.__all__ == [*names, "__version__"]
    for name in names:
        value = getattr(brdfscale, name)
        where = brdfscale._LAZY[name]
        if where == f".{name}":
            assert value is importlib.import_module(f"brdfscale.{name}")
        else:
            assert value is getattr(importlib.import_module(where, "brdfscale"), name)
    # the TYPE_CHECKING block and the eager exception imports name the same modules for the same names
    tree = ast.parse(Path(brdfscale.__file__).read_text())
    declared = {}
    top = [*tree.body, *(n for node in tree.body if isinstance(node, ast.If) for n in node.body)]  # TYPE_CHECKING
    for node in top:
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            for alias in node.names:
                declared[alias.name] = f".{alias.name}" if node.module is None else f".{node.module}"
    assert declared == brdfscale._LAZY


@pytest.mark.parametrize("argv", [["--help"], ["info", "{file}"]])
def test_command_line_starts_without_jax(tmp_path, argv):
    import numpy as np

    from brdfscale import exr, LobeImage, MeasurementSet

    path = tmp_path / "m.exr"
    exr.write_measurements(
        path,
        MeasurementSet(
            tuple(
                LobeImage(mu=mu, incident=np.array([0.0, 0.0, 1.0]), extent=0.5, values=np.ones((8, 8)))
                for mu in (1.0, 2.0)
            )
        ),
    )
    argv = [a.format(file=path) for a in argv]
    got = _run(f"""
        import contextlib, io, json, sys
        from brdfscale._cli import main
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                code = main({argv!r})
            except SystemExit as exit:
                code = exit.code
        print(json.dumps({{"code": code, "jax": "jax" in sys.modules, "matplotlib": "matplotlib" in sys.modules}}))
    """)
    assert got == {"code": 0, "jax": False, "matplotlib": False}
