"""Exception classes of brdfscale.

Every error raised on bad input derives from :class:`BrdfscaleError`, so a script can catch
all of brdfscale's complaints at once.  The messages name what was wrong and what would
have been accepted.
"""


class BrdfscaleError(Exception):
    """Base class of all errors raised by brdfscale."""


class InvalidInputError(BrdfscaleError, ValueError):
    """An argument has the wrong shape, dtype, range or type."""


class SingularDensityError(BrdfscaleError, ValueError):
    """A point evaluation was asked of a distribution that has no pointwise density (δ)."""


class NoBRDFAtScaleError(BrdfscaleError, ValueError):
    """No non-negative BRDF exists at the requested scale.

    Raised when the evolution towards a finer scale would need, for example, a Gaussian
    lobe of negative variance, or a lobe whose transform exceeds 1 in modulus (which no
    non-negative density has).
    """


class MethodNotApplicableError(BrdfscaleError, ValueError):
    """A forced evolution path (``method=...``) cannot handle the given inputs."""


class MeasurementFileError(BrdfscaleError):
    """A measurement or lobe-table file cannot be read or written as asked.

    Raised for missing, truncated, corrupted or malformed OpenEXR files (the message names
    the file, the part and the attribute or channel at fault), and when writing would
    overwrite an existing file without ``overwrite=True``.
    """


class MissingDependencyError(BrdfscaleError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it
    (e.g. ``pip install "brdfscale[topography]"`` for instrument files)."""


class OutputInUseError(BrdfscaleError):
    """Another run holds the lock on an output directory or checkpoint.

    Raised at once, before any work, by the writers of runs (:func:`fitting.sample` with a
    checkpoint, :func:`fitting.write_report`, ``brdfscale fit``/``demo``); the message names
    the holder (PID, host, start time, command). See :func:`brdfscale.files.exclusive`.
    """


class UnprotectedHeaderWarning(UserWarning):
    """A file of an earlier layout version whose header attributes carry no digest: its
    pixels are checked against their checksums, its μ, extent, incident direction and
    metadata are not. Rewrite it (read and write again) to protect them."""


class UnresolvedMethodError(BrdfscaleError, ValueError):
    """A spectral path's discretisation depends on parameter values that are traced.

    Raised by :func:`brdfscale.evolve` inside ``jax.jit``/``grad``/``vmap`` when the method has
    no node count (radial) or grid side (grid): resolve it with :func:`brdfscale.select` from
    concrete values outside the transformation, and pass the resolved method in.
    """
