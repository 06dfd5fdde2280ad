"""Objects that show themselves: compact summaries as text and HTML, and progress bars.

Every public object of brdfscale and :mod:`fitting` derives from :class:`Shown`, whose
``__repr__`` is a few lines (at most :data:`MAX_LINES`, :data:`MAX_CHARS` characters) and whose
``_repr_html_`` is a small table (Jupyter shows it when the object is a cell's value). The
summary lists what a class names as its key parameters (``_show_items``); arrays appear as
their dtype and shape (``f64[33,33]``), numbers and short vectors (at most three entries, e.g.
a slope mean) with four significant digits. Values that are not concrete — tracers inside
``jax.jit``/``vmap``/``grad``, the ``jax.ShapeDtypeStruct`` leaves of ``jax.eval_shape`` —
appear as dtype and shape too, so a summary never fails and never adds work to a trace
(derived parameters of abstract values are shaped with ``jax.eval_shape``). ``equinox.tree_pformat(x)``
still prints every field of a module. Tested in tests/test_show.py.

:func:`progress_bar` is the one progress bar of the library (:func:`fitting.sample`, the
experiments): tqdm's notebook widget in a Jupyter kernel with ipywidgets installed, otherwise
tqdm's text bar (on stderr), with no warning either way; off with ``enabled=False`` or, for
every bar, the environment variable ``BRDFSCALE_PROGRESS=0``.

This module imports neither JAX nor matplotlib: :class:`brdfscale.LobeImage` and
:class:`brdfscale.MeasurementSet` show themselves on JAX-free paths (``brdfscale info``).
"""

import dataclasses
import html
import math
import os
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence

from ._errors import InvalidInputError


__all__ = [
    "Shown",
    "Table",
    "Values",
    "derived",
    "concrete",
    "summary",
    "summary_html",
    "describe",
    "progress_bar",
    "progress_mode",
    "PROGRESS_VARIABLE",
    "MAX_LINES",
    "MAX_CHARS",
]

MAX_LINES = 6
"""The most lines a summary (``repr``) takes."""
MAX_CHARS = 400
"""The most characters a summary (``repr``) takes."""
_WIDTH = 88  # line width of a wrapped summary
_ITEM_CHARS = 160  # the most characters one item's value takes in a summary
_INLINE_CHARS = (160, 70)  # … an object as an item of a summary, and one nested deeper
_TABLE_ROWS = 40  # rows of an HTML table before "… n more"
_SHORT = 3  # concrete arrays with at most this many entries appear as their values
PROGRESS_VARIABLE = "BRDFSCALE_PROGRESS"
"""The environment variable that switches every progress bar: ``0`` (or ``false``, ``off``, ``no``)
off, ``text`` the text bar even in a notebook, ``1``/``auto``/unset the default."""

_DTYPES = {
    "float64": "f64",
    "float32": "f32",
    "float16": "f16",
    "bfloat16": "bf16",
    "complex128": "c128",
    "complex64": "c64",
    "int64": "i64",
    "int32": "i32",
    "int16": "i16",
    "int8": "i8",
    "uint64": "u64",
    "uint32": "u32",
    "uint8": "u8",
    "bool": "bool",
}


# -- values -----------------------------------------------------------------------------------


def _jax():
    """The jax module if it is imported (no value can be a JAX array otherwise), else None."""
    return sys.modules.get("jax")


def _is_array(x) -> bool:
    return hasattr(x, "shape") and hasattr(x, "dtype") and not isinstance(x, type)


def _is_abstract(x) -> bool:
    """True for values without data: tracers and ``jax.ShapeDtypeStruct``."""
    jax = _jax()
    return jax is not None and isinstance(x, (jax.core.Tracer, jax.ShapeDtypeStruct))


def concrete(tree) -> bool:
    """True when every leaf of ``tree`` holds values: no tracer (inside ``jax.jit``/``vmap``/``grad``)
    and no ``jax.ShapeDtypeStruct`` (from ``jax.eval_shape``)."""
    jax = _jax()
    if jax is None:
        return True
    return not any(_is_abstract(leaf) for leaf in jax.tree_util.tree_leaves(tree))


def _shape_text(x) -> str:
    """``f64[33,33]``: dtype and shape."""
    name = str(getattr(x.dtype, "name", x.dtype))
    return f"{_DTYPES.get(name, name)}[{','.join(str(int(n)) for n in x.shape)}]"


def _number(v) -> str:
    """A number with four significant digits (integers as they are)."""
    if isinstance(v, (bool,)) or type(v).__name__ == "bool_":
        return str(bool(v))
    if isinstance(v, complex) or type(v).__name__.startswith("complex"):
        v = complex(v)
        return f"{_number(v.real)}{'+' if v.imag >= 0 else '−'}{_number(abs(v.imag))}j"
    if isinstance(v, int) or type(v).__name__.startswith(("int", "uint")):
        return str(int(v))
    v = float(v)
    if math.isnan(v) or math.isinf(v):
        return str(v)
    return f"{v:.4g}"


class Values:
    """An array shown by its values up to ``limit`` entries (e.g. the scales of a dataset), by
    dtype and shape beyond that or when abstract."""

    __slots__ = ("value", "limit")

    def __init__(self, value, limit: int = 8):
        self.value, self.limit = value, limit


def _array_text(x, limit: int = _SHORT) -> str:
    if _is_abstract(x):
        return _shape_text(x)
    size = math.prod(int(n) for n in x.shape)
    if size > limit or len(x.shape) > 1:
        return _shape_text(x)
    import numpy as np

    a = np.asarray(x)
    if a.ndim == 0:
        return _number(a[()])
    return "(" + ", ".join(_number(v) for v in a.tolist()) + ")"


def _truncate(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "…"


def describe(value, limit: int = _ITEM_CHARS) -> str:
    """One value as summary text (at most ``limit`` characters): arrays as dtype and shape or,
    short and concrete, their values; numbers with four significant digits; objects that show
    themselves inline; other modules and dataclasses by their type and fields."""
    return _truncate(_describe(value, depth=0), limit)


def _describe(value, depth: int) -> str:
    if value is None or isinstance(value, str):
        return str(value)
    if isinstance(value, Values):
        return _array_text(value.value, value.limit) if _is_array(value.value) else _describe(value.value, depth)
    if isinstance(value, (bool, int, float, complex)):
        return _number(value)
    if _is_array(value):
        return _array_text(value)
    if isinstance(value, type):
        return value.__name__
    if isinstance(value, Shown) or _is_module(value) or dataclasses.is_dataclass(value):
        return _inline(value, depth)
    if isinstance(value, Mapping):
        inner = ", ".join(f"{k}: {_describe(v, depth + 1)}" for k, v in list(value.items())[:4])
        return "{" + inner + (", …" if len(value) > 4 else "") + "}"
    if isinstance(value, (tuple, list)):
        if len(value) > 4:
            return f"({len(value)} items)"
        inner = ", ".join(_describe(v, depth + 1) for v in value)
        return f"({inner}{',' if len(value) == 1 else ''})"
    if callable(value) and hasattr(value, "__name__"):
        return value.__name__
    return _truncate(repr(value), 40)


def _is_module(x) -> bool:
    eqx = sys.modules.get("equinox")
    return eqx is not None and isinstance(x, eqx.Module)


def _inline(obj, depth: int) -> str:
    """``Type(k=v, …)`` on one line, nested objects two levels deep."""
    name = type(obj).__name__
    if depth >= 2:
        return f"{name}(…)"
    parts = [f"{k}={_describe(v, depth + 1)}" if k else _describe(v, depth + 1) for k, v in _items(obj)]
    return _truncate(f"{name}({', '.join(parts)})", _INLINE_CHARS[min(depth, 1)])


def derived(x, fn: Callable):
    """``fn(x)`` for a concrete array ``x`` (NumPy), its ``jax.ShapeDtypeStruct`` for an abstract
    one (``jax.eval_shape``: nothing is added to a trace). ``fn`` must work on NumPy and JAX
    arrays alike (indexing, arithmetic, ``** 0.5``)."""
    if x is None:
        return None
    if _is_abstract(x):
        jax = _jax()
        assert jax is not None  # an abstract value is a JAX one: jax is imported
        return jax.eval_shape(fn, jax.ShapeDtypeStruct(x.shape, x.dtype))
    import numpy as np

    return fn(np.asarray(x))


# -- what an object shows ----------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Table:
    """An extra table of an HTML summary (e.g. a fit's parameters): a caption, the column
    names and the rows (values are shown with :func:`describe`)."""

    caption: str
    columns: tuple[str, ...]
    rows: Sequence[Sequence]


def _items(obj) -> list[tuple[str, object]]:
    """The (name, value) pairs an object shows: its ``_show_items`` or, for other modules and
    dataclasses, every field that is neither None nor empty. A summary must not fail where it
    is asked for (a notebook cell, a traceback, a debugger): an error while collecting the
    items is shown as the one item, by its type and message."""
    try:
        if isinstance(obj, Shown):
            return list(obj._show_items())
        return _field_items(obj, ())
    except Exception as err:  # noqa: BLE001 — shown, not swallowed: the summary names it
        return [("", f"summary failed: {type(err).__name__}: {err}")]


def _field_items(obj, hidden) -> list[tuple[str, object]]:
    items = []
    for f in dataclasses.fields(obj):
        if f.name in hidden or f.name.startswith("_"):
            continue
        value = getattr(obj, f.name, None)
        if value is not None and not (isinstance(value, (tuple, list, dict)) and not value):
            items.append((f.name, value))
    return items


class Shown:
    """Mixin: a compact ``repr`` and ``_repr_html_`` from the key parameters a class names.

    Subclasses override ``_show_items()`` (a list of ``(name, value)`` pairs; an empty name
    shows the value alone) and, for HTML, ``_show_tables()`` (a list of :class:`Table`). The
    default shows every dataclass field that is neither None nor empty, except those in
    ``_show_hidden``.
    """

    __slots__ = ()
    _show_hidden: tuple[str, ...] = ("isotropic",)

    def _show_items(self) -> list[tuple[str, object]]:
        return _field_items(self, type(self)._show_hidden)

    def _show_tables(self) -> list[Table]:
        return []

    def __repr__(self) -> str:
        return summary(self)

    def _repr_html_(self) -> str:
        return summary_html(self)


def summary(obj) -> str:
    """``repr`` of an object that shows itself: ``Type(k=v, …)``, wrapped at 88 characters, at
    most :data:`MAX_LINES` lines and :data:`MAX_CHARS` characters (items that do not fit are
    left out, marked ``…``)."""
    parts = [f"{k}={describe(v)}" if k else describe(v) for k, v in _items(obj)]
    lines, shown = [type(obj).__name__ + "("], 0
    for part in parts:
        joined = lines[-1] + ("" if lines[-1].endswith("(") else " ") + part + ","
        candidate = lines[:-1] + [joined] if len(joined) <= _WIDTH else lines + ["  " + part + ","]
        if len(candidate) > MAX_LINES or sum(len(line) + 1 for line in candidate) + 4 > MAX_CHARS:
            break
        lines, shown = candidate, shown + 1
    text = "\n".join(lines).removesuffix(",")
    if shown < len(parts):
        text += ", …" if shown else "…"
    return text + ")"


def _cell(value) -> str:
    return "—" if value is None else html.escape(describe(value, 200))


def summary_html(obj) -> str:
    """``_repr_html_`` of an object that shows itself: a two-column table of its items, then
    its extra tables (each at most 40 rows, then a row saying how many more)."""
    name = html.escape(type(obj).__name__)
    rows = "".join(
        f'<tr><th style="text-align:left">{html.escape(k)}</th><td style="text-align:left">{_cell(v)}</td></tr>'
        for k, v in _items(obj)
    )
    out = [
        f'<table class="brdfscale-summary"><thead><tr><th colspan="2" style="text-align:left">{name}</th>'
        f"</tr></thead><tbody>{rows}</tbody></table>"
    ]
    try:
        tables = obj._show_tables() if isinstance(obj, Shown) else []
    except Exception as err:  # noqa: BLE001 — as in _items: named in the summary, not raised
        tables = [Table("summary failed", ("error",), [(f"{type(err).__name__}: {err}",)])]
    for table in tables:
        head = "".join(f"<th>{html.escape(c)}</th>" for c in table.columns)
        body = []
        for row in list(table.rows)[:_TABLE_ROWS]:
            body.append("<tr>" + "".join(f"<td>{_cell(v)}</td>" for v in row) + "</tr>")
        if len(table.rows) > _TABLE_ROWS:
            body.append(f'<tr><td colspan="{len(table.columns)}">… {len(table.rows) - _TABLE_ROWS} more</td></tr>')
        out.append(
            f'<table class="brdfscale-summary"><caption style="text-align:left">{html.escape(table.caption)}'
            f"</caption><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"
        )
    return "\n".join(out)


# -- progress bars ---------------------------------------------------------------------------

_OFF = ("0", "false", "off", "no")
_ON = ("", "1", "true", "on", "yes", "auto")


def _in_jupyter_kernel() -> bool:
    """True inside a Jupyter kernel (notebook, lab, VS Code), not a terminal IPython or a
    Qt console (which cannot show widgets). Imports nothing that is not imported already."""
    if "ipykernel" not in sys.modules:
        return False
    ipython = sys.modules.get("IPython")
    shell = getattr(ipython, "get_ipython", lambda: None)() if ipython is not None else None
    if type(shell).__name__ != "ZMQInteractiveShell":
        return False
    return not any(k == "QT_API" or k.startswith("SPYDER") for k in os.environ)


def _notebook_bar():
    """tqdm's notebook bar class when ipywidgets can draw it, else None (no warning)."""
    import importlib.util

    if importlib.util.find_spec("ipywidgets") is None:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            from tqdm import notebook
        except ImportError:
            return None
    return notebook.tqdm if getattr(notebook, "IProgress", None) is not None else None


def progress_mode() -> str:
    """``"off"``, ``"notebook"`` or ``"text"``: what :func:`progress_bar` shows here.

    ``"off"`` when ``BRDFSCALE_PROGRESS`` is ``0``/``false``/``off``/``no``; ``"notebook"`` in a
    Jupyter kernel where ipywidgets is installed (unless ``BRDFSCALE_PROGRESS=text``); else
    ``"text"``.

    Raises:
        InvalidInputError: ``BRDFSCALE_PROGRESS`` holds another value (the message lists the
            accepted ones).
    """
    setting = os.environ.get(PROGRESS_VARIABLE, "").strip().lower()
    if setting in _OFF:
        return "off"
    if setting not in _ON and setting != "text":
        raise InvalidInputError(
            f"the environment variable {PROGRESS_VARIABLE} is {os.environ[PROGRESS_VARIABLE]!r}; use 0 (no progress "
            "bars), text (text bars even in a notebook) or 1/auto (the default), or unset it."
        )
    if setting != "text" and _in_jupyter_kernel() and _notebook_bar() is not None:
        return "notebook"
    return "text"


def progress_bar(iterable=None, *, enabled: bool = True, **options):
    """A tqdm progress bar that suits where it runs (see :func:`progress_mode`).

    Args:
        iterable: what to iterate over, as for ``tqdm(iterable)``; None for a bar advanced by
            ``bar.update(n)`` (give ``total=``).
        enabled: False gives a disabled bar (nothing shown); also off for every bar with
            ``BRDFSCALE_PROGRESS=0``.
        options: passed to tqdm (``total``, ``desc``, ``unit``, ``initial``, ``mininterval``, …).

    Returns a ``tqdm`` object (a context manager), of ``tqdm.notebook`` in a Jupyter kernel
    with ipywidgets, else of ``tqdm.std``; neither warns.

    Raises:
        InvalidInputError: ``enabled`` is not a bool, or ``BRDFSCALE_PROGRESS`` holds a value
            :func:`progress_mode` does not accept.
    """
    if not isinstance(enabled, bool) and type(enabled).__name__ != "bool_":
        raise InvalidInputError(f"progress must be True or False; got {type(enabled).__name__} {enabled!r}.")
    mode = progress_mode()
    bar = _notebook_bar() if mode == "notebook" else None  # not None in a notebook (progress_mode checked it)
    if bar is None:
        from tqdm.std import tqdm as bar
    return bar(iterable, disable=not enabled or mode == "off", **options)


#: Metric units for lengths in metres, largest first (a figure's axis or a printed table shows the
#: largest that fits).
DISPLAY_UNITS = (("m", 1.0), ("mm", 1e-3), ("µm", 1e-6), ("nm", 1e-9), ("pm", 1e-12))


def display_unit(mus) -> tuple[str, float]:
    """The metric unit (name, size in metres) in which the largest of ``mus`` (metres) is ≥ 1
    (``brdfscale topography``'s output and :func:`brdfscale.plot.facet_statistics`)."""
    top = max(mus)
    for name, size in DISPLAY_UNITS:
        if top / size >= 1:
            return name, size
    return DISPLAY_UNITS[-1]
