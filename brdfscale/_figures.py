"""The one seam between the library and :mod:`brdfscale.plot` (docs/architecture.md).

Objects keep their figures as methods — ``lobe.plot()``, ``density.plot()``, ``law.plot(mu=…)``,
``mset.plot()``, ``plan.plot()``, ``samples.plot()`` — but the plot package sits above every
layer those objects live in (it imports them to draw them). :func:`draw` names the figure
function of :mod:`brdfscale.plot` and imports that package only when a user asks for a
figure, so no model module depends on it (nor on matplotlib) at import or at run time
otherwise. This is the single allowed import of a higher layer; tests/test_layers.py allows
exactly this edge and checks that nothing else below the plot package imports it.
"""

import importlib


def draw(figure: str, *args, **options):
    """``brdfscale.plot.<figure>(*args, **options)``: a ``matplotlib.figure.Figure``."""
    return getattr(importlib.import_module("brdfscale.plot"), figure)(*args, **options)
