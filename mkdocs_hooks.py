"""Hooks of the documentation build (mkdocs.yml, ``hooks:``).

docs/results.md shows the studies' figures where the studies write them,
``../experiments/results/<study>/<figure>.png`` (a link that works on the repository's own
pages). mkdocs only publishes files under docs/, so the build adds those figures to the site as
``experiments/results/...`` and points the pages' links there; the figures are not copied into
docs/.
"""

import re
from pathlib import Path

from mkdocs.structure.files import File


FIGURES = Path(__file__).resolve().parent / "experiments" / "results"
LINK = re.compile(r"\]\(\.\./experiments/results/")


def on_files(files, config):
    for path in sorted(FIGURES.rglob("*.png")):
        if not path.name.endswith("_quick.png"):  # quick runs' local output (.gitignore)
            uri = "experiments/results/" + path.relative_to(FIGURES).as_posix()
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files


def on_page_markdown(markdown, page, config, files):
    if "/" not in page.file.src_uri:  # a page directly under docs/: ../ is the repository root
        markdown = LINK.sub("](experiments/results/", markdown)
    return markdown


# -- docstrings ------------------------------------------------------------------------------
# The docstrings cross-reference in Sphinx's roles (:class:`X`, :func:`~a.b`), which Markdown
# would show as ":class:" followed by the name. This griffe extension (mkdocs.yml, the python
# handler's ``extensions``) renders each as the name in code; ``~`` keeps its last component.

import griffe  # noqa: E402


ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj):`(~?)([^`]+)`")


def _code(match: re.Match) -> str:
    name = match.group(2)
    return f"`{name.rsplit('.', 1)[-1] if match.group(1) else name}`"


class SphinxRoles(griffe.Extension):
    def on_instance(self, *, obj, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = ROLE.sub(_code, obj.docstring.value)
