"""The tutorial notebooks in docs/tutorials/ run from top to bottom without an error (issue 17).

They are executed with nbclient in a fresh Jupyter kernel, in a temporary working directory,
as a reader would run them; every figure a cell returns must reach the notebook as a PNG.
Executing them takes minutes, so it is marked ``tutorials`` (deselected by default; .ci/run
runs them as a step of its own). The committed files carry no outputs — checked by default.
"""

import json
import re
from pathlib import Path

import pytest


TUTORIALS = sorted((Path(__file__).resolve().parent.parent / "docs" / "tutorials").glob("*.ipynb"))


def test_there_are_tutorials():
    assert [p.name for p in TUTORIALS] == [
        "01_tour.ipynb",
        "02_your_own_arrays.ipynb",
        "03_your_own_surface.ipynb",
        "04_instrument.ipynb",
        "05_render.ipynb",
    ]


@pytest.mark.parametrize("path", TUTORIALS, ids=lambda p: p.stem)
def test_committed_notebooks_are_stripped(path):
    nb = json.loads(path.read_text())
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            assert cell["outputs"] == [] and cell["execution_count"] is None, f"{path.name}: strip the outputs"
    assert nb["metadata"]["kernelspec"]["name"] == "python3"


@pytest.mark.tutorials
@pytest.mark.parametrize("path", TUTORIALS, ids=lambda p: p.stem)
def test_tutorial_runs(path, tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's own choice, as in a reader's Jupyter
    nb = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(
        nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    figures = 0
    for cell in nb.cells:
        for output in cell.get("outputs", []):
            assert output["output_type"] != "error", output
            text = output.get("data", {}).get("text/plain", "")
            if re.match(r"<\w*Figure size", text):
                figures += 1
                assert "image/png" in output["data"], f"a figure reached the notebook without a PNG: {text}"
    assert figures >= 3
