"""The documentation: what it cites, where its links lead, its tables, and the examples and
names of docs/core.md.

Nothing here builds the site (CI runs ``mkdocs build --strict``, which needs the ``docs``
extra); these checks need only the repository.
"""

import ast
import contextlib
import importlib
import io
import re
import subprocess
import unicodedata
from pathlib import Path

import jax
import pytest


ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.rglob("*.md")) + [ROOT / "README.md"]
CORE = DOCS / "core.md"


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


# -- citations of files outside the repository ----------------------------------------------------

# The project's design notes and field notes live outside the repository (a user's clone has
# neither): the repository cites its own docs/conventions.md and docs/dependencies.md instead.
# The names are assembled here so that this file does not cite them itself.
OUTSIDE = re.compile(rb"\b" + b"DES" + rb"IGN\b|" + b"FIELD" + b"-NOTES")
CHECKED = ("brdfscale/", "fitting/", "experiments/", "tests/", "docs/", "README.md")


def _tracked_files() -> list[str]:
    """The files git tracks, or would track (new and not ignored), under CHECKED."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard", "--", *CHECKED],
            cwd=ROOT,
            capture_output=True,
            check=True,
        )
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: every file there
        return sorted(
            _rel(p)
            for c in CHECKED
            for p in ([ROOT / c] if c.endswith(".md") else (ROOT / c).rglob("*"))
            if p.is_file() and "__pycache__" not in p.parts
        )
    return sorted(name for name in out.stdout.decode().split("\0") if name)


def test_no_file_cites_notes_outside_the_repository():
    files = _tracked_files()
    assert "README.md" in files and "brdfscale/__init__.py" in files
    hits = []
    for name in files:
        path = ROOT / name
        if not path.is_file():  # deleted in the working tree, not yet in git
            continue
        for number, line in enumerate(path.read_bytes().splitlines(), 1):
            if OUTSIDE.search(line):
                hits.append(f"{name}:{number}: {line.decode(errors='replace').strip()[:120]}")
    assert not hits, (
        "cite docs/conventions.md §n or docs/dependencies.md instead of notes outside the "
        "repository:\n" + "\n".join(hits)
    )


# -- Markdown: the parts outside code ---------------------------------------------------------------

FENCE = re.compile(r"^\s*(```|~~~)")


def _prose_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, line) of the page outside fenced code blocks."""
    lines, fenced = [], False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced:
            lines.append((number, line))
    return lines


def _without_code_spans(line: str) -> str:
    return re.sub(r"(`+)(.+?)\1", lambda m: " " * len(m.group(0)), line)


def _plain_heading(text: str) -> str:
    """A heading's text as rendered: links by their text, code and emphasis by their content."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)
    return text.replace("`", "").replace("*", "").strip()


def _slug_mkdocs(text: str) -> str:
    """Python-Markdown's toc.slugify (mkdocs' default)."""
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def _slug_github(text: str) -> str:
    """GitHub's heading anchors: lower case, punctuation dropped, each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    """The anchors that both mkdocs and GitHub give the page's headings."""
    mkdocs, github = set(), set()
    for _, line in _prose_lines(path):
        m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
        if m:
            text = _plain_heading(m.group(2))
            mkdocs.add(_slug_mkdocs(text))
            github.add(_slug_github(text))
    return mkdocs & github


LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def _links(path: Path):
    for number, line in _prose_lines(path):
        for m in LINK.finditer(_without_code_spans(line)):
            yield number, m.group(1)


def test_relative_links_lead_to_files_and_anchors_that_exist():
    problems, checked = [], 0
    for page in PAGES:
        for number, target in _links(page):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, https:, mailto:
                continue
            file_part, _, anchor = target.partition("#")
            destination = (page.parent / file_part).resolve() if file_part else page
            checked += 1
            where = f"{_rel(page)}:{number}: {target}"
            if not destination.exists():
                problems.append(f"{where}: no such file")
            elif anchor and destination.suffix == ".md" and anchor not in _anchors(destination):
                problems.append(
                    f"{where}: no heading of {destination.name} has the anchor #{anchor} (on both GitHub and the site)"
                )
    assert checked > 20, checked  # the pages do link to each other
    assert not problems, "\n".join(problems)


# -- Markdown tables --------------------------------------------------------------------------------

SEPARATOR = re.compile(r"^\s*\|?\s*:?-+:?\s*(\|\s*:?-+:?\s*)*\|?\s*$")


def _cells(line: str) -> list[str]:
    """The cells of a table row as GitHub splits them: on every ``|`` that is not escaped, inside
    code spans too."""
    row = line.strip()
    row = row[1:] if row.startswith("|") else row
    row = row[:-1] if row.endswith("|") and not row.endswith("\\|") else row
    return re.split(r"(?<!\\)\|", row)


def _tables(path: Path):
    """(line number of the header, [(line number, line), ...]) for every table of the page."""
    lines = _prose_lines(path)
    k = 0
    while k + 1 < len(lines):
        (n0, head), (n1, sep) = lines[k], lines[k + 1]
        if "|" in head and n1 == n0 + 1 and SEPARATOR.match(sep) and "-" in sep:
            rows = [(n0, head), (n1, sep)]
            k += 2
            while k < len(lines) and lines[k][0] == rows[-1][0] + 1 and lines[k][1].strip() and "|" in lines[k][1]:
                rows.append(lines[k])
                k += 1
            yield n0, rows
        else:
            k += 1


def test_every_table_has_as_many_cells_in_each_row_as_in_its_header():
    problems, count = [], 0
    for page in PAGES:
        for start, rows in _tables(page):
            count += 1
            widths = [len(_cells(line)) for _, line in rows]
            if len(set(widths)) != 1:
                bad = [f"line {n}: {w}" for (n, _), w in zip(rows, widths) if w != widths[0]]
                problems.append(f"{_rel(page)}:{start}: header {widths[0]} cells; " + ", ".join(bad))
            # GitHub needs \| for a pipe inside a code span in a table, the site then shows the
            # backslash: a table cell must not hold a pipe in code at all
            for n, line in rows:
                for span in re.findall(r"(`+)(.+?)\1", line):
                    if "|" in span[1]:
                        problems.append(f"{_rel(page)}:{n}: a '|' inside the code span `{span[1]}` of a table")
    assert count > 40, count
    assert not problems, "\n".join(problems)


# -- docs/core.md -----------------------------------------------------------------------------------


def _python_blocks(path: Path) -> list[tuple[int, str]]:
    blocks, current, start = [], None, 0
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if current is None and re.match(r"^```python\s*$", line):
            current, start = [], number + 1
        elif current is not None and line.startswith("```"):
            blocks.append((start, "\n".join(current) + "\n"))
            current = None
        elif current is not None:
            current.append(line)
    assert current is None, f"{_rel(path)}: a python block is not closed"
    return blocks


@pytest.mark.slow  # 14 s on 2 cores: the default suite measured 402 s at ff4fa2c (budget 360)
def test_core_examples_run(tmp_path, monkeypatch):
    """Every python block of docs/core.md, in order, in one namespace, in float64 (the first
    block switches it on, as a user's script would)."""
    blocks = _python_blocks(CORE)
    assert len(blocks) >= 6
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__core_examples__"}
    with contextlib.redirect_stdout(io.StringIO()):
        for line, code in blocks:
            exec(compile(code, f"{CORE}:{line}", "exec"), namespace)  # noqa: S102 — the page's own examples
    assert jax.config.jax_enable_x64


def _core_table() -> list[list[str]]:
    text = CORE.read_text(encoding="utf-8")
    section = text[text.index("## From the seed's equations to the code") :]
    rows = [line for line in section.splitlines() if line.startswith("|")]
    header = [c.strip() for c in _cells(rows[0])]
    assert header == ["seed", "what it says", "implemented by", "checked by"], header
    return [[c.strip() for c in _cells(r)] for r in rows[2:]]


def _resolve(name: str):
    """The object a fully qualified public name refers to (modules imported as needed)."""
    parts = name.split(".")
    assert not any(p.startswith("_") for p in parts), f"{name} is not a public name"
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(name)


def _test_ids(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    ids = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith("test"):
            ids.add(node.name)
        elif isinstance(node, ast.ClassDef) and node.name.startswith("Test"):
            ids |= {
                f"{node.name}::{f.name}"
                for f in node.body
                if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)) and f.name.startswith("test")
            }
    return ids


def test_core_table_covers_the_seeds_equations():
    equations = {row[0] for row in _core_table()}
    wanted = {f"Eq. {n}" for n in ("2.1", "3.1", "4.2", "4.3", "4.4", "5.1", "5.2", "5.3", "5.4", "6.1")}
    assert wanted <= equations, sorted(wanted - equations)


@pytest.mark.parametrize("row", _core_table(), ids=lambda row: row[0])
def test_core_table_names_functions_that_import_and_tests_that_exist(row):
    _, _, implemented, checked = row
    names = re.findall(r"`([^`]+)`", implemented)
    tests = re.findall(r"`([^`]+)`", checked)
    assert names and tests, row
    for name in names:
        try:
            _resolve(name)
        except (ImportError, AttributeError) as err:
            pytest.fail(f"docs/core.md names {name}, which does not import: {err!r}")
    for test in tests:
        file, sep, test_id = test.partition("::")
        assert sep and file.startswith("tests/") and file.endswith(".py"), test
        path = ROOT / file
        assert path.is_file(), f"docs/core.md cites {test}: no file {file}"
        assert test_id in _test_ids(path), f"docs/core.md cites {test}: no such test in {file}"


# -- the site's navigation --------------------------------------------------------------------------


def test_every_page_is_in_the_sites_navigation_and_every_entry_exists():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = config[config.index("\nnav:") : config.index("\nmarkdown_extensions:")]
    entries = set(re.findall(r":\s*(\S+\.md)\s*$", nav, re.M))
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    assert entries == pages, {
        "not in the navigation": sorted(pages - entries),
        "in the navigation, missing": sorted(entries - pages),
    }


# -- docs/topography.md ("Your own surface") --------------------------------------------------------

TOPOGRAPHY = DOCS / "topography.md"


def _python_blocks_and_output(path: Path) -> list[tuple[int, str, str | None]]:
    """(first line, code, text shown under it) of every python block; the shown text is a
    ``text`` block following the python block with only blank lines between, else None."""
    lines = path.read_text(encoding="utf-8").splitlines()
    fenced, k = [], 0  # (language, first body line, opening line index, closing line index, body)
    while k < len(lines):
        m = re.match(r"^```(\w+)\s*$", lines[k])
        if m:
            opening = k
            k += 1
            while k < len(lines) and not lines[k].startswith("```"):
                k += 1
            assert k < len(lines), f"{_rel(path)}:{opening + 1}: a {m.group(1)} block is not closed"
            fenced.append((m.group(1), opening + 2, opening, k, "\n".join(lines[opening + 1 : k]) + "\n"))
        k += 1
    out = []
    for n, (language, first, _, closing, body) in enumerate(fenced):
        if language == "python":
            following = fenced[n + 1] if n + 1 < len(fenced) else None
            shown = (
                following[4]
                if following
                and following[0] == "text"
                and not any(line.strip() for line in lines[closing + 1 : following[2]])
                else None
            )
            out.append((first, body, shown))
    return out


@pytest.mark.slow  # 17 s on 2 cores: the default suite measured 402 s at ff4fa2c (budget 360)
def test_topography_examples_run_and_print_what_the_page_shows(monkeypatch):
    """Every python block of docs/topography.md, in order, in one namespace, from the
    repository root (the page reads tests/data/topographies/); each block's output has the
    words and numbers of the text block shown under it (the page may wrap long lines). Needs
    the topography extra, as the page does."""
    pytest.importorskip("SurfaceTopography", reason="docs/topography.md reads instrument files (brdfscale[topography])")
    blocks = _python_blocks_and_output(TOPOGRAPHY)
    assert len(blocks) >= 8 and sum(shown is not None for *_, shown in blocks) >= 6
    monkeypatch.chdir(ROOT)
    namespace = {"__name__": "__topography_examples__"}
    problems = []
    for line, code, shown in blocks:
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            exec(compile(code, f"{TOPOGRAPHY}:{line}", "exec"), namespace)  # noqa: S102 — the page's own examples
        if shown is not None and printed.getvalue().split() != shown.split():
            problems.append(f"docs/topography.md:{line} prints\n{printed.getvalue()}\nbut the page shows\n{shown}")
    assert not problems, "\n".join(problems) + "\n(python -m experiments.topography_page --update-text rewrites them)"
    # the figures the page shows are those its code draws (experiments/topography_page.py saves each fig_<name>)
    from matplotlib.figure import Figure

    drawn = {k[4:] for k, v in namespace.items() if k.startswith("fig_") and isinstance(v, Figure)}
    shown = set(re.findall(r"\]\(\.\./experiments/results/topography_page/(\w+)\.png\)", TOPOGRAPHY.read_text()))
    assert drawn and drawn == shown, (drawn, shown)
    for name in shown:
        assert (ROOT / "experiments" / "results" / "topography_page" / f"{name}.png").is_file(), name


def _difference_quotients(topo, steps, untrimmed=False):
    """SurfaceTopography's forward difference quotients at scale factors ``steps`` (a list of
    (x, y) pairs), transposed to rows y, columns x. For a non-periodic topography it trims
    both axes of both components by the stencil's reach, also the rows the x quotient does not
    need; ``untrimmed`` computes them as if periodic (the windows' slopes use no wrapped value)."""
    import numpy as np

    qx, qy = topo.derivative(1, scale_factor=steps, interpolation="disable", periodic=True if untrimmed else None)
    return [np.asarray(q).T for q in qx], [np.asarray(q).T for q in qy]


def _row_means(qx, qy, block, grid):
    """The facets' slopes from the quotients: −(mean over the window's rows of the x quotient
    at its left column, mean over its columns of the y quotient at its top row)."""
    (by, bx), (rows, cols) = block, grid
    mx = -qx[: rows * by].reshape(rows, by, -1).mean(axis=1)[:, ::bx][:, :cols]
    my = -qy[:, : cols * bx].reshape(-1, cols, bx).mean(axis=2)[::by][:rows]
    return mx, my


def test_facet_slopes_are_row_means_of_surface_topographys_difference_quotients():
    """docs/topography.md §6: the facet slope at μ = bΔ is minus the mean over the window's
    b rows of SurfaceTopography's difference quotient at distance ℓ = μ (exactly, square and
    non-square pixels); at one pixel Σ = N/(N−1) times its slope variance; beyond, Σ(μ) is
    below its slope variance at ℓ = μ — on the AFM file, and on a simulated isotropic surface,
    where Σ also matches the stationary formula b⁻² Σ_{|k|<b} (b − |k|) C_ℓ(kΔ) built from
    SurfaceTopography's quotients within the stated standard errors."""
    st = pytest.importorskip(
        "SurfaceTopography", reason="the comparison needs SurfaceTopography (brdfscale[topography])"
    )
    import numpy as np

    from brdfscale import stats, synth, topography

    # the real AFM file, square pixels
    field = topography.read(ROOT / "tests" / "data" / "topographies" / "di-3.di", detrend="curvature")
    theirs = (
        st.open_topography(str(ROOT / "tests" / "data" / "topographies" / "di-3.di")).topography().detrend("curvature")
    )
    steps = [1, 2, 3, 4, 8, 16, 25, 32, 64]
    qx, qy = _difference_quotients(theirs, [(b, b) for b in steps])
    ux, uy = _difference_quotients(theirs, [(b, b) for b in steps], untrimmed=True)
    for k, (b, s) in enumerate(
        zip(steps, synth.facet_statistics(field, [b * field.spacing[0] for b in steps], bins=9))
    ):
        dx, dy = qx[k], qy[k]
        m = synth.facet_slopes(field, s.mu)
        mx, my = _row_means(ux[k], uy[k], (b, b), m.shape[:2])
        np.testing.assert_allclose(mx, m[..., 0], rtol=0, atol=1e-13)
        np.testing.assert_allclose(my, m[..., 1], rtol=0, atol=1e-13)
        if b == 1:
            n = s.count
            assert n == dx.size == dy.size
            np.testing.assert_allclose(
                np.diag(s.covariance), n / (n - 1) * np.array([np.var(dx), np.var(dy)]), rtol=1e-12
            )
        else:
            assert s.covariance[0, 0] < np.var(dx) and s.covariance[1, 1] < np.var(dy), b

    # non-square pixels (Δy = 3Δx), the same heights in both libraries, nothing removed
    periodic = synth.spectral_field(stats.GaussianCorrelation(0.3, 6.0), size=128, seed=5)
    heights = periodic.heights[:90, :120]
    dx, dy = 0.5, 1.5
    mine = topography.from_array(heights, (dx, dy), unit="m", detrend=None)
    topo = st.Topography(heights.T, (120 * dx, 90 * dy), periodic=False)
    for mu in (1.5, 4.5, 9.0):
        by, bx = mine.block(mu)
        (qx,), (qy,) = _difference_quotients(topo, [(bx, by)], untrimmed=True)
        m = synth.facet_slopes(mine, mu)
        mx, my = _row_means(qx, qy, (by, bx), m.shape[:2])
        np.testing.assert_allclose(mx, m[..., 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(my, m[..., 1], rtol=0, atol=1e-12)

    # a simulated isotropic surface: Σ(μ) from the row covariances of the quotients
    periodic = synth.spectral_field(stats.GaussianCorrelation(0.2, 8.0), size=512, seed=11)
    field = topography.from_array(periodic.heights[:400, :400], 1.0, unit="m", detrend=None)
    topo = st.Topography(field.heights.T, (400.0, 400.0), periodic=False)
    steps = [2, 4, 8, 16]
    qx, _ = _difference_quotients(topo, [(b, b) for b in steps])
    for b, s, q in zip(steps, synth.facet_statistics(field, [float(b) for b in steps], bins=9), qx):
        q = q - q.mean()
        cov = [np.mean(q[k:] * q[: q.shape[0] - k]) for k in range(b)]  # C_ℓ(kΔ) between rows k apart
        predicted = (b * cov[0] + 2 * sum((b - k) * cov[k] for k in range(1, b))) / b**2
        assert s.covariance[0, 0] < np.var(q), b
        assert abs(s.covariance[0, 0] - predicted) < 3 * s.covariance_error[0, 0], (b, s.covariance[0, 0], predicted)
