"""Mitsuba 3, imported on demand, with a variant that runs on this machine (the one place that decides it).

:mod:`brdfscale.instrument` and :mod:`brdfscale.render` call :func:`mitsuba` when they need the ray tracer; nothing
imports Mitsuba at import time and nothing selects a variant before a call asks for one (Mitsuba's variant is
process-wide state). Facts behind the choices (docs/dependencies.md, "Mitsuba 3.9.1 with Dr.Jit 1.5.0"):

* the LLVM variants (``llvm_ad_rgb``) abort the process — not an exception — with Debian 12's default LLVM 15
  (``LLVM ERROR: Cannot select: f32 = fminimum``, even on the stock Cornell box); Debian's ``libllvm19`` fixes it
  and Dr.Jit finds it by itself. Dr.Jit reports the LLVM it loaded (``drjit.detail.llvm_version()``), so an LLVM
  older than :data:`LLVM_TESTED` is refused *before* anything is compiled;
* the scalar variants (``scalar_rgb``) need no LLVM; they are ~8× slower for a Python BSDF.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ._errors import InvalidInputError, MissingDependencyError


LLVM_TESTED = (19,)
"""The oldest LLVM major version the LLVM variants were run with here; LLVM 15 aborts the process."""

PREFERRED = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
"""The default variant: the first of these this machine can run (a GPU, then the CPU's LLVM JIT, then scalar)."""

INSTALL = 'pip install "brdfscale[render]"  (Mitsuba 3 ≥ 3.9.1 and Dr.Jit ≥ 1.5.0)'
INSTALL_LLVM = "apt-get install libllvm19  (Debian/Ubuntu; or set DRJIT_LIBLLVM_PATH to an LLVM ≥ 19 library)"


def _import(name: str) -> ModuleType:
    try:
        return importlib.import_module(name)
    except ImportError as err:
        raise MissingDependencyError(f"the ray tracer Mitsuba 3 is not installed ({err}); install: {INSTALL}") from err


def llvm_problem() -> str | None:
    """Why Mitsuba's LLVM variants cannot run here (one line), or None when they can."""
    dr = _import("drjit")
    if not dr.has_backend(dr.JitBackend.LLVM):
        return f"Dr.Jit found no LLVM library; install one: {INSTALL_LLVM}"
    version = tuple(importlib.import_module("drjit.detail").llvm_version())
    if version[:1] < LLVM_TESTED:
        found = ".".join(map(str, version))
        return f"Dr.Jit loaded LLVM {found}, with which Mitsuba's LLVM variants abort; install: {INSTALL_LLVM}"
    return None


def available(variant: str) -> str | None:
    """Why ``variant`` cannot run here (one line), or None when it can."""
    mi = _import("mitsuba")
    if variant not in mi.variants():
        return f"Mitsuba variant {variant!r} is not in this build; it has {', '.join(mi.variants())}"
    if variant.startswith("llvm_"):
        return llvm_problem()
    if variant.startswith("cuda_"):
        dr = _import("drjit")
        if not dr.has_backend(dr.JitBackend.CUDA):
            return f"Mitsuba variant {variant!r} needs an NVIDIA GPU with its driver; none was found"
    return None


def mitsuba(variant: str | None = None) -> ModuleType:
    """The ``mitsuba`` module with ``variant`` selected (default: the first of :data:`PREFERRED` that runs here).

    Raises :class:`MissingDependencyError` naming what to install when Mitsuba is missing or the variant asked for
    cannot run (an LLVM variant with an LLVM older than :data:`LLVM_TESTED`), and :class:`InvalidInputError` for a
    name Mitsuba does not know. Verified in tests/test_mitsuba.py.
    """
    mi = _import("mitsuba")
    if variant is None:
        for candidate in PREFERRED:
            if available(candidate) is None:
                variant = candidate
                break
        else:  # scalar_rgb is in every build
            why = available("scalar_rgb")
            raise MissingDependencyError(f"no Mitsuba variant runs here ({why}); install: {INSTALL}")
    elif not isinstance(variant, str) or variant not in mi.variants():
        raise InvalidInputError(f"variant must be one of Mitsuba's {', '.join(mi.variants())}; got {variant!r}")
    problem = available(variant)
    if problem is not None:
        raise MissingDependencyError(problem)
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi
