"""The isotropic (slope-space) evolution operator, seed Eq. 4.4, and its paths as objects.

One module per job: :mod:`._flow` (``evolve``/``select``: the one flow, asking the method
objects), :mod:`._method` (the abstract method), one module per path — :mod:`._closed_form`,
:mod:`._radial`, :mod:`._grid`, :mod:`._auto` — :mod:`._spectral` (the evolved density's exact
transform, the spectral bounds and what the two spectral paths share), :mod:`._algebra` (closed
forms) and :mod:`._regularise` (Tikhonov λ rules).
"""

from .._errors import UnresolvedMethodError
from ._algebra import has_closed_form
from ._auto import Auto
from ._closed_form import ClosedForm
from ._flow import (
    as_method,
    check_arguments,
    evolve,
    MethodName,
    RegularisationName,
    select,
)
from ._grid import Grid, MAX_GRID
from ._method import AbstractMethod, achievable_tol, MIN_TOL
from ._radial import MAX_RADIAL_NODES, Radial, RadialTable
from ._regularise import CANDIDATES as REGULARISATION_CANDIDATES, choose as choose_regularisation, DEFAULT_RULE, RULES
from ._spectral import (
    AbstractSpectralMethod,
    CORE_TOL,
    cutoff,
    EvolvedDensity,
    grid_size,
    probe_checks,
    radial_nodes,
    radial_reach,
)


__all__ = [
    "CORE_TOL",
    "DEFAULT_RULE",
    "MAX_GRID",
    "MAX_RADIAL_NODES",
    "MIN_TOL",
    "REGULARISATION_CANDIDATES",
    "RULES",
    "AbstractMethod",
    "AbstractSpectralMethod",
    "Auto",
    "ClosedForm",
    "EvolvedDensity",
    "Grid",
    "MethodName",
    "Radial",
    "RadialTable",
    "RegularisationName",
    "UnresolvedMethodError",
    "achievable_tol",
    "as_method",
    "check_arguments",
    "choose_regularisation",
    "cutoff",
    "evolve",
    "grid_size",
    "has_closed_form",
    "probe_checks",
    "radial_nodes",
    "radial_reach",
    "select",
]
