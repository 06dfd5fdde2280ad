"""JAX's persistent compilation cache for the ``brdfscale`` command.

Every run of ``brdfscale fit`` or ``brdfscale demo`` is a new process that would compile the
same XLA programs again (the fit's solve alone takes seconds); with the cache, later runs
read them from disk. The command enables it before its subcommand runs — a global JAX
setting, so it belongs at this edge and not in the library:

* directory: ``$BRDFSCALE_COMPILATION_CACHE`` if set, else
  ``$XDG_CACHE_HOME/brdfscale/jax`` (``~/.cache/brdfscale/jax`` without ``XDG_CACHE_HOME``);
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


def enable() -> Path | None:
    """Point JAX's persistent compilation cache at :func:`cache_directory` unless JAX already
    has one; returns the directory in use (None when none is).

    With JAX imported, through ``jax.config``; before it is, through the environment variables
    JAX reads when it is imported (``JAX_COMPILATION_CACHE_DIR``, …), so a command that never
    needs JAX in its own process (``fit-library`` driving Ray tasks) does not import it for
    this, and the processes it starts inherit the setting."""
    jax = sys.modules.get("jax")
    configured = jax.config.jax_compilation_cache_dir if jax is not None else os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if configured:  # the user's own JAX setting wins
        return Path(configured)
    path = cache_directory()
    try:
        path.mkdir(parents=True, exist_ok=True)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(f"no write permission on {path}")
    except OSError as err:
        print(f"brdfscale: compilation cache off ({err}); set BRDFSCALE_COMPILATION_CACHE to a writable "
              "directory or pass --no-compilation-cache", file=sys.stderr)
        return None
    settings = {"jax_compilation_cache_dir": str(path), "jax_persistent_cache_min_compile_time_secs": 0.0,
                "jax_persistent_cache_min_entry_size_bytes": 0, "jax_compilation_cache_max_size": MAX_BYTES}
    for name, value in settings.items():
        if jax is not None:
            jax.config.update(name, value)
        else:
            os.environ[name.upper()] = str(value)
    return path
