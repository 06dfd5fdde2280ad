"""JAX's persistent compilation cache, set up in one place for the ``brdfscale`` command and
for the processes that fit a library (:func:`brdfscale.library.fit_library`'s Ray tasks).

Every run of ``brdfscale fit`` or ``brdfscale demo`` is a new process that would compile the
same XLA programs again (the fit's solve alone takes seconds); with the cache, later runs
read them from disk. The command enables it before its subcommand runs, and hands the
directory to the library's worker processes, which enable it with the same settings — a
global JAX setting, so it belongs to these applications and not to the library's functions:

* directory: ``$BRDFSCALE_COMPILATION_CACHE`` if set, else
  ``$XDG_CACHE_HOME/brdfscale/jax`` (``~/.cache/brdfscale/jax`` without ``XDG_CACHE_HOME``);
  a worker uses the directory its driver gives it;
* every program is kept, however quickly it compiled (a fit compiles about a hundred small
  ones besides the solve), up to :data:`MAX_BYTES` in all, least recently used first out;
* a cache the user configured for JAX (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)``) is left as it is;
* ``brdfscale --no-compilation-cache …`` switches it off; a directory that cannot be
  created or written is reported on stderr and the run goes on without a cache.

JAX keys each entry by the program, the compile options, the backend and the library
versions, so a stale entry is never used; programs with host callbacks are not cached (JAX
refuses them).
"""

import os
import sys
from pathlib import Path


MAX_BYTES = 256 * 2**20


def cache_directory() -> Path:
    """Where the command keeps compiled programs (see the module docstring)."""
    explicit = os.environ.get("BRDFSCALE_COMPILATION_CACHE")
    if explicit:
        return Path(explicit).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "brdfscale" / "jax"


def settings(path: str | os.PathLike) -> dict:
    """JAX's settings of a cache in ``path``: the directory, every program kept, the size cap."""
    return {
        "jax_compilation_cache_dir": str(path),
        "jax_persistent_cache_min_compile_time_secs": 0.0,
        "jax_persistent_cache_min_entry_size_bytes": 0,
        "jax_compilation_cache_max_size": MAX_BYTES,
    }


def directory_in_use() -> str | None:
    """The persistent compilation cache directory this process uses or will use, if any (the
    one :func:`enable` set, or the user's own): JAX's setting once JAX is imported, else the
    environment variable JAX will read."""
    jax = sys.modules.get("jax")
    return jax.config.jax_compilation_cache_dir if jax is not None else os.environ.get("JAX_COMPILATION_CACHE_DIR")


def enable(directory: str | os.PathLike | None = None) -> Path | None:
    """Point JAX's persistent compilation cache at ``directory`` (default
    :func:`cache_directory`; a library worker gets its driver's) with every setting of
    :func:`settings`, unless JAX already has one; returns the directory in use (None when none is).

    With JAX imported, through ``jax.config``; before it is, through the environment variables
    JAX reads when it is imported (``JAX_COMPILATION_CACHE_DIR``, …), so a command that never
    needs JAX in its own process (``fit-library`` driving Ray tasks) does not import it for
    this, and the processes it starts inherit the setting."""
    jax = sys.modules.get("jax")
    configured = directory_in_use()
    if configured:  # the user's own JAX setting wins
        return Path(configured)
    path = cache_directory() if directory is None else Path(directory)
    try:
        path.mkdir(parents=True, exist_ok=True)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(f"no write permission on {path}")
    except OSError as err:
        print(
            f"brdfscale: compilation cache off ({err}); set BRDFSCALE_COMPILATION_CACHE to a writable "
            "directory or pass --no-compilation-cache",
            file=sys.stderr,
        )
        return None
    for name, value in settings(path).items():
        if jax is not None:
            jax.config.update(name, value)
        else:
            os.environ[name.upper()] = str(value)
    return path
