"""experiments/ is a folder of scripts run from the checkout (``python -m experiments.NAME``), not
a package that ``pip install`` puts on every user's path, and none of its scripts edits
``sys.path`` (issue 17)."""

import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"


def test_pip_install_leaves_experiments_out():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    find = config["tool"]["setuptools"]["packages"]["find"]
    assert not any(pattern.startswith("experiments") for pattern in find.get("include", []))
    assert set(find["include"]) == {"brdfscale*", "fitting*"}
    # the tests import experiments from the checkout, not from an installed copy
    assert "." in config["tool"]["pytest"]["ini_options"]["pythonpath"]


def test_no_experiment_edits_sys_path():
    offenders = [p.name for p in EXPERIMENTS.rglob("*.py") if "sys.path" in p.read_text()]
    assert offenders == []


def test_experiments_import_their_helpers_through_the_package():
    """``from _bench import …`` or ``import results_page`` works only with the script's folder on
    the path: the scripts import ``experiments._bench``, ``experiments.results_page`` and so on."""
    names = "|".join(p.stem for p in EXPERIMENTS.glob("*.py") if p.name != "__init__.py")
    local = re.compile(rf"^\s*(from|import) ({names})\b", re.M)
    offenders = [p.name for p in EXPERIMENTS.glob("*.py") if local.search(p.read_text())]
    assert offenders == []


def test_commands_name_the_module_not_the_file():
    """Docs, README and docstrings give ``python -m experiments.NAME``; ``python experiments/<name>.py``
    would fail to import the helpers."""
    texts = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *EXPERIMENTS.glob("*.py"), *(ROOT / "tests").glob("*.py"),
             *(ROOT / "brdfscale").rglob("*.py"), *(ROOT / "fitting").rglob("*.py")]
    old = re.compile(r"python3?\s+experiments/\w+\.py")
    offenders = [str(p.relative_to(ROOT)) for p in texts if old.search(p.read_text())]
    assert offenders == []


def test_a_script_runs_as_a_module_from_the_checkout():
    out = subprocess.run([sys.executable, "-m", "experiments.benchmarks_page", "--help"], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("usage:")
