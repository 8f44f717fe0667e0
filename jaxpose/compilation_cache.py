"""JAX's persistent compilation cache for the command lines: a second run reads the train step and the
other programs it compiled from disk instead of compiling them again.

The folder: `$JAXPOSE_COMPILATION_CACHE` (a folder, or `off` for no cache), else
`$XDG_CACHE_HOME/jaxpose/xla`, else `~/.cache/jaxpose/xla`.  A cache that JAX was already given
(`JAX_COMPILATION_CACHE_DIR`, or `jax.config.update("jax_compilation_cache_dir", ...)` before) is left
as it is, thresholds included.  A cached program is the one that was compiled, so results do not change.
The cache is trusted code (JAX's warning): a folder that others can write lets them run code in your
process, so keep it private.  A cache entry that cannot be written (several processes writing one folder
at once, a full disk) costs only the next run's compilation: JAX warns at every compilation, which this
module turns into one log line per process (`quiet_write_errors`).
"""

from __future__ import annotations

import errno
import importlib.util
import logging
import os
import pathlib
import warnings
from collections.abc import Mapping

import jax

log = logging.getLogger("jaxpose")

ENVIRONMENT = "JAXPOSE_COMPILATION_CACHE"
OFF = "off"
# Cache what takes this long to compile: the train and evaluation steps take seconds, and the loading
# path's many small programs add up (fractions of a second each); the rest is not worth a file.
MIN_COMPILE_TIME_S = 0.1
# Least recently used programs are deleted past this size (JAX's default is no limit at all), where
# the filelock package that JAX's eviction needs is installed; without it the folder grows until deleted.
MAX_SIZE_BYTES = 2 * 1024**3
WRITE_ERROR = "Error writing persistent compilation cache entry"  # the start of JAX's warning


def cache_folder(environ: Mapping[str, str] = os.environ) -> pathlib.Path | None:
    """The folder the command lines cache compiled programs in (None: `JAXPOSE_COMPILATION_CACHE=off`)."""
    chosen = environ.get(ENVIRONMENT, "").strip()
    if chosen.lower() == OFF:
        return None
    if chosen:
        return pathlib.Path(chosen).expanduser()
    base = pathlib.Path(environ.get("XDG_CACHE_HOME", "").strip())
    # The XDG rule: a relative XDG_CACHE_HOME is ignored.
    return (base if base.is_absolute() else pathlib.Path.home() / ".cache") / "jaxpose" / "xla"


def enable_compilation_cache(environ: Mapping[str, str] = os.environ) -> str | None:
    """Turn the persistent compilation cache on (call it before the first compilation); returns its
    folder, or None where it is off or cannot be written (a warning says so).  A cache JAX was already
    given is kept as it is."""
    if jax.config.jax_compilation_cache_dir:
        return jax.config.jax_compilation_cache_dir
    folder = cache_folder(environ)
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))
    except OSError as error:  # else JAX warns at every compilation
        log.warning("no compilation cache: %s cannot be written (%s); set %s to another folder, or to off", folder, error.strerror, ENVIRONMENT)
        return None
    quiet_write_errors(str(folder))
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    if importlib.util.find_spec("filelock") is not None:
        jax.config.update("jax_compilation_cache_max_size", MAX_SIZE_BYTES)
    log.debug("persistent compilation cache in %s (%s=off to disable)", folder, ENVIRONMENT)
    return str(folder)


def quiet_write_errors(folder: str) -> None:
    """Show JAX's warning that a cache entry could not be written once, as a log line, instead of at every
    compilation; every other warning is shown as before."""
    previous = warnings.showwarning
    if getattr(previous, "jaxpose_quiet", False):
        return
    said = False

    def show(message, category, filename, lineno, file=None, line=None):
        nonlocal said
        if not str(message).startswith(WRITE_ERROR):
            return previous(message, category, filename, lineno, file, line)
        if not said:
            said = True
            reason = str(message).split(": ", 1)[-1]
            log.warning(
                "the compilation cache %s could not take a program (%s): it runs as usual and is compiled again next time;"
                " further such errors are not shown (%s=off, or another folder, if it persists)", folder, reason, ENVIRONMENT
            )

    show.jaxpose_quiet = True
    warnings.showwarning = show
