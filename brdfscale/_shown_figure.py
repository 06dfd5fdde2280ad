"""The Figure class of brdfscale's figures (:mod:`brdfscale._figure_style`; imports matplotlib: loaded when a
figure is drawn)."""

import io

from matplotlib.figure import Figure


class ShownFigure(Figure):
    """A ``matplotlib.figure.Figure`` that Jupyter shows as a PNG when it is a cell's value.

    A Figure made without pyplot has no display formatter of its own: IPython registers one
    for Figure only when pyplot's inline backend is loaded, and without it a notebook prints
    ``<Figure size ...>``. ``_repr_png_`` draws it instead (where the inline formatter is
    registered, IPython uses that one: it matches this class through Figure). Tested by
    executing the tutorials (tests/test_tutorials.py: every figure reaches the notebook as a PNG).
    """

    def _repr_png_(self) -> bytes:
        buffer = io.BytesIO()
        self.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
        return buffer.getvalue()
