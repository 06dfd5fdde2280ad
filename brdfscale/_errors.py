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


class OutputWriteError(BrdfscaleError):
    """A file could not be written: the disk is full (``ENOSPC``/``EDQUOT``), the quota is
    spent, or the operating system reported another I/O error at one step of the write.

    Raised by every writer of brdfscale (:func:`brdfscale.files.atomic_write` and the
    writers built on it: EXR files, JSON indices and reports, figures, checkpoints). The
    one-line message names the file, the operating system's error (a full disk as "disk
    full") and the free space left on that file system. Nothing is left in the file's
    place: an existing file is unchanged and the temporary file is removed. The command
    line exits with status 8. ``path``, ``errno`` (or None), ``free`` (bytes, or None when
    unknown) and ``disk_full`` are attributes.
    """

    def __init__(self, message: str, *, path: str = "", errno: int | None = None, free: int | None = None):
        super().__init__(message)
        self.path, self.errno, self.free = path, errno, free

    @property
    def disk_full(self) -> bool:
        import errno as _errno

        return self.errno in (_errno.ENOSPC, getattr(_errno, "EDQUOT", _errno.ENOSPC))


class UnprotectedHeaderWarning(UserWarning):
    """A file of an earlier layout version whose header attributes carry no digest: its
    pixels are checked against their checksums, its μ, extent, incident direction and
    metadata are not. Rewrite it (read and write again) to protect them."""


class LobeCutWarning(UserWarning):
    """A synthesised or ray-traced lobe image holds less of its lobe's light than
    :data:`brdfscale.synth.LIGHT_INSIDE` (95 %): the image's extent is too small for the lobe — typically a rough
    micro-facet lobe, whose tails the default extent (:func:`brdfscale.synth.robust_extent`, from the pixel slopes)
    does not count. Warned by :func:`brdfscale.synth.gonioreflectometer` and :func:`brdfscale.instrument.measure`;
    the message names the worst scale, the share and the fix (a larger extent)."""


class ToleranceRelaxedWarning(UserWarning):
    """An evaluation honours a looser error than the ``tol`` asked (e.g. a capped FFT grid that
    cannot resolve a heavy-tailed or very narrow lobe to it). The tolerance honoured is recorded
    where the result is explained (``result.shape.tol``, ``...discretisation.explain()``)."""


class UnresolvedMethodError(BrdfscaleError, ValueError):
    """A spectral path's discretisation depends on parameter values that are traced.

    Raised by :func:`brdfscale.evolve` inside ``jax.jit``/``grad``/``vmap`` when the method has
    no node count (radial) or grid side (grid): resolve it with :func:`brdfscale.select` from
    concrete values outside the transformation, and pass the resolved method in.
    """
