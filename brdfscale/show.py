"""How brdfscale's objects show themselves, and its progress bars, for code built on brdfscale.

* :class:`Shown` — the mixin behind every compact ``repr`` and ``_repr_html_`` (lobes,
  statistics, evolved lobes, measurement sets, plans, and :mod:`fitting`'s datasets and
  results): a class names its key parameters in ``_show_items()`` (and extra HTML tables in
  ``_show_tables()``, :class:`Table`); arrays appear as dtype and shape (``f64[33,33]``),
  numbers with four significant digits, abstract values (under ``jax.jit``, ``jax.eval_shape``)
  by dtype and shape, so a summary never fails;
* :func:`summary`, :func:`summary_html`, :func:`describe` — the same text for any object;
  :class:`Values`, :func:`derived`, :func:`concrete` — helpers for ``_show_items``;
* :func:`progress_bar` — a tqdm bar that is the notebook widget in a Jupyter kernel with
  ipywidgets, else the text bar, without a warning either way; off per call
  (``enabled=False``) or for every bar with the environment variable ``BRDFSCALE_PROGRESS=0``
  (``text``: the text bar even in a notebook); :func:`progress_mode` says which applies.

Importing this module imports neither JAX nor matplotlib. Tested in tests/test_show.py.
"""

from ._show import (
    concrete,
    derived,
    describe,
    MAX_CHARS,
    MAX_LINES,
    progress_bar,
    progress_mode,
    PROGRESS_VARIABLE,
    Shown,
    summary,
    summary_html,
    Table,
    Values,
)


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
