"""experiments/ is a folder of scripts run from the checkout (``python -m experiments.NAME``), not
a package that ``pip install`` puts on every user's path, and none of its scripts edits
``sys.path``; the tests import no experiment and no other test module (shared fixtures in
tests/helpers.py, independent references in tests/references/); ``requires-python`` is the
Python the code and the tests need."""

import ast
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest


ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"


def test_pip_install_leaves_experiments_out():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    packages = config["tool"]["setuptools"]["packages"]
    # only brdfscale's packages are installed: no experiments, no tests, no generic top-level `fitting`
    assert packages and all(name == "brdfscale" or name.startswith("brdfscale.") for name in packages)
    # tests.helpers, tests.references and experiments/ are imported from the checkout, not installed
    assert "." in config["tool"]["pytest"]["ini_options"]["pythonpath"]


def test_no_experiment_edits_sys_path():
    offenders = [p.name for p in EXPERIMENTS.rglob("*.py") if "sys.path" in p.read_text()]
    assert offenders == []


def test_experiments_import_their_helpers_through_the_package():
    """``from _bench import …`` or ``import results_page`` works only with the script's folder on
    the path: the scripts import ``experiments._bench``, ``experiments.results_page`` and so on."""
    names = "|".join(p.stem for p in EXPERIMENTS.glob("*.py") if p.name != "__init__.py")
    local = re.compile(rf"^\s*(from|import) ({names})\b", re.MULTILINE)
    offenders = [p.name for p in EXPERIMENTS.glob("*.py") if local.search(p.read_text())]
    assert offenders == []


def test_commands_name_the_module_not_the_file():
    """Docs, README and docstrings give ``python -m experiments.NAME``; ``python experiments/<name>.py``
    would fail to import the helpers."""
    texts = [
        ROOT / "README.md",
        *(ROOT / "docs").glob("*.md"),
        *EXPERIMENTS.glob("*.py"),
        *(ROOT / "tests").glob("*.py"),
        *(ROOT / "brdfscale").rglob("*.py"),
        *(ROOT / "fitting").rglob("*.py"),
    ]
    old = re.compile(r"python3?\s+experiments/\w+\.py")
    offenders = [str(p.relative_to(ROOT)) for p in texts if old.search(p.read_text())]
    assert offenders == []


def test_a_script_runs_as_a_module_from_the_checkout():
    out = subprocess.run(
        [sys.executable, "-m", "experiments.benchmarks_page", "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage:")


#: the one test module that imports experiments/: it checks the scripts' own functions in-process
#: (their parts against closed forms, smoke runs, the pages they generate; its docstring says why)
EXPERIMENTS_ALLOWED = {"test_experiments_smoke.py"}


def _imported_modules(source: str) -> list[str]:
    """Every module ``source`` imports, at any depth (imports inside functions included);
    relative imports as ``.name``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            out.append(base)
            if not node.module:  # from . import test_x
                out += [base + alias.name for alias in node.names]
    return out


def test_tests_import_no_experiment_and_no_other_test_module():
    """Test modules share fixtures through tests/helpers.py and oracles through
    tests/references/, never by importing one another or an experiment script (a test would
    then depend on a benchmark's code, and collecting one test file would run another's)."""
    tests = ROOT / "tests"
    offenders = []
    for path in sorted(tests.rglob("*.py")):
        name = str(path.relative_to(tests))
        for module in _imported_modules(path.read_text()):
            parts = module.lstrip(".").split(".")
            if parts[0] == "tests":
                parts = parts[1:]
            if (parts and parts[0] == "experiments" and path.name not in EXPERIMENTS_ALLOWED) or (
                parts and (parts[0].startswith("test_") or parts[0] == "conftest")
            ):
                offenders.append(f"{name}: import {module}")
    assert offenders == []


def test_the_import_check_sees_what_it_should():
    """The check above catches each form of the imports it forbids (so it cannot pass by
    missing them)."""
    source = (
        "import experiments.bench_fit\nfrom experiments import _bench\nfrom test_fit import X\n"
        "def f():\n    from tests.test_samplers import Linear\n    from . import test_x\n"
        "from tests.helpers import Linear\nfrom tests.references import planner\n"
    )
    assert sorted(_imported_modules(source)) == sorted(
        [
            "experiments.bench_fit",
            "experiments",
            "test_fit",
            "tests.test_samplers",
            ".",
            ".test_x",
            "tests.helpers",
            "tests.references",
        ]
    )


def test_requires_python_is_what_the_code_and_tests_need():
    """``tomllib`` (this file) and BlackJAX 1.7 (fitting.NUTS, fitting.HMC) need Python 3.11:
    ``requires-python`` says so, no dependency carries a marker for an older Python, and the
    README's quick start names the same version."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert config["project"]["requires-python"] == ">=3.11"
    assert sys.version_info >= (3, 11)
    markers = [d for d in config["project"]["dependencies"] if "python_version" in d]
    assert markers == []
    assert "Python ≥ 3.11" in (ROOT / "README.md").read_text()


def test_a_shadowing_copy_of_the_package_names_the_installed_one(tmp_path):
    """A copy of the package in a script's folder shadows the installed brdfscale; a name it
    lacks raises AttributeError naming both locations and the way out (brdfscale/_shadow.py).
    The installed package itself gives the plain message."""
    from brdfscale._shadow import _installed_location

    installed = _installed_location()
    if installed is None or Path(installed[1]).resolve() != ROOT / "brdfscale":
        pytest.skip("brdfscale is not installed from this checkout (pip install -e .)")
    shutil.copytree(ROOT / "brdfscale", tmp_path / "brdfscale", ignore=shutil.ignore_patterns("__pycache__"))
    script = (
        "import brdfscale\ntry:\n    brdfscale.not_a_name\nexcept AttributeError as err:\n    print(err)\n"
        "print(brdfscale.__file__)\n"
    )
    (tmp_path / "script.py").write_text(script)
    out = subprocess.run(
        [sys.executable, "script.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300, check=True
    ).stdout.splitlines()
    assert out[1] == str(tmp_path / "brdfscale" / "__init__.py")  # the copy was imported
    assert out[0].startswith("module 'brdfscale' has no attribute 'not_a_name' (this brdfscale is ")
    assert str(ROOT / "brdfscale") in out[0] and "-P" in out[0]
    # the installed package: no hint
    plain = subprocess.run(
        [sys.executable, "-P", "script.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300, check=True
    ).stdout.splitlines()
    assert plain[0] == "module 'brdfscale' has no attribute 'not_a_name'"
    assert plain[1] == str(ROOT / "brdfscale" / "__init__.py")
