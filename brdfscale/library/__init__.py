"""Material libraries: many measurement sets fitted with one set of options, in batches, in this
process or across the hosts of a Ray cluster, resumable, with nothing lost (docs/library.md).

* :func:`fit_library` — the driver: finds the materials (:func:`find_materials`), hands
  batches to :func:`fitting.fit_many` (one compiled program per bucket of a batch) in this
  process or as Ray tasks (the optional extra ``brdfscale[cluster]``), keeps the index
  ``OUT/library.json`` and returns a :class:`LibraryResult`;
* :class:`FitSpec` — the model and options every material is fitted with;
* ``brdfscale fit-library DIR_OR_FILES... --out DIR`` — the same on the command line.

What is where in ``OUT``: ``library.json`` (options, runs, per material its source, status,
χ²/dof, error, attempts), ``materials/NAME/`` (the report of :func:`fitting.write_report`:
``fit.json``, figures, ``evolved_lobes.exr``; ``posterior.nc`` when sampled, and the checkpoint ``chain.h5`` of a
sampler that runs per material: emcee, imh, auto).
"""

from ._run import find_materials, fit_library, INDEX, LibraryResult
from ._spec import FitSpec, make_model, model_class


__all__ = ["fit_library", "FitSpec", "LibraryResult", "find_materials", "make_model", "model_class", "INDEX"]
