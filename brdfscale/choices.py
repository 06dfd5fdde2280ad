"""The names a fit accepts and the defaults of its options, in one table (JAX-free).

* :data:`SOLVERS`, :data:`SAMPLERS`, :data:`MODELS`, :data:`SHAPES`, :data:`INCREMENTS`, :data:`FAMILIES`,
  :data:`LAWS`, :data:`MASKING` — each a :class:`Choices`: the accepted names in order, a one-line description of each
  (``SAMPLERS.summary("nuts")``, ``SAMPLERS.help()``) and the default (``SAMPLERS.default``);
* :data:`INSTRUMENTS`, :data:`WEIGHTINGS`, :data:`MICRO_FACETS` — ``brdfscale synth``'s ``--instrument``,
  ``--weighting`` (also ``synth.gonioreflectometer``'s) and ``--micro``; :data:`BINNINGS`, :data:`MESHES`,
  :data:`EXECUTORS` — :mod:`brdfscale.instrument`'s detector binnings, meshes (``surface=``) and executors (also
  :func:`brdfscale.library.fit_library`'s); :data:`FORMS`, :data:`OUTPUTS`, :data:`FOOTPRINTS` —
  :mod:`brdfscale.render`'s material forms and its integrator's outputs and footprints;
* :class:`FitDefaults`, :class:`SampleDefaults`, :class:`ModelDefaults` and their defaults
  :data:`FIT`, :data:`SAMPLE`, :data:`MODEL` — what ``fitting.fit``/``fit_many``,
  ``fitting.sample``/``sample_many``, the fitting models, :class:`brdfscale.library.FitSpec`
  and the ``brdfscale fit``/``fit-library`` options default to (``FIT.starts`` is ``"auto"``: the model's
  ``preferred_starts``, ``FIT.model_starts`` = 8 unless the model says otherwise);
* :data:`MIN_FIT_SCALES` — the fewest distinct scales a fit accepts (2);
* :class:`AdequacyDefaults` and :data:`ADEQUACY` — the thresholds of ``fitting.assess`` (the
  outcome of a fit and the command's exit statuses 5–7).

Tested in tests/test_choices.py: every name is accepted by fitting and by the command, and
the command's and the functions' defaults are these.
"""

from ._choices import (
    ADEQUACY,
    AdequacyDefaults,
    BINNINGS,
    Choice,
    Choices,
    EXECUTORS,
    FAMILIES,
    FIT,
    FitDefaults,
    FOOTPRINTS,
    FORMS,
    INCREMENTS,
    INSTRUMENTS,
    LAWS,
    MASKING,
    MESHES,
    MICRO_FACETS,
    MIN_FIT_SCALES,
    MODEL,
    ModelDefaults,
    MODELS,
    OUTPUTS,
    SAMPLE,
    SampleDefaults,
    SAMPLERS,
    SHAPES,
    SOLVERS,
    WEIGHTINGS,
)


__all__ = [
    "ADEQUACY",
    "BINNINGS",
    "EXECUTORS",
    "FAMILIES",
    "FIT",
    "FOOTPRINTS",
    "FORMS",
    "INCREMENTS",
    "INSTRUMENTS",
    "LAWS",
    "MASKING",
    "MESHES",
    "MICRO_FACETS",
    "MIN_FIT_SCALES",
    "MODEL",
    "MODELS",
    "OUTPUTS",
    "SAMPLE",
    "SAMPLERS",
    "SHAPES",
    "SOLVERS",
    "WEIGHTINGS",
    "Choice",
    "Choices",
    "AdequacyDefaults",
    "FitDefaults",
    "ModelDefaults",
    "SampleDefaults",
]
