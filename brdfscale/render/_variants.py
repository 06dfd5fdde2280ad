"""Mitsuba classes built once per variant: Mitsuba's types (``mi.BSDF``, ``mi.SamplingIntegrator``, its arrays)
depend on the variant, so the BSDF (:mod:`._plugin`) and the integrator (:mod:`._integrator`) are built for each
variant the first time it asks for them, and kept."""

import functools
import threading
from collections.abc import Callable


def per_variant(build: Callable[..., type]) -> Callable[..., type]:
    """A decorator: ``build(mi)`` called once per variant of ``mi`` (``mi.variant()``), its class kept and returned
    after that; thread-safe (one lock per builder). The decorated function keeps its name and docstring."""
    built: dict[str, type] = {}
    lock = threading.Lock()

    @functools.wraps(build)
    def cls(mi) -> type:
        variant = mi.variant()
        with lock:
            if variant not in built:
                built[variant] = build(mi)
            return built[variant]

    return cls
