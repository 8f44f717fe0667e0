"""JAX's persistent compilation cache for the command lines: a second run reads the train step and the
other programs it compiled from disk instead of compiling them again.

The folder: `$JAXPOSE_COMPILATION_CACHE` (a folder, or `off` for no cache), else
`$XDG_CACHE_HOME/jaxpose/xla`, else `~/.cache/jaxpose/xla`.  A cache that JAX was already given
(`JAX_COMPILATION_CACHE_DIR`, or `jax.config.update("jax_compilation_cache_dir", ...)` before) is left
as it is, thresholds included.  A cached program is the one that was compiled, so results do not change.
The cache is trusted code (JAX's warning): a folder that others can write lets them run code in your
process, so keep it private.  Its size is bounded by JAX's eviction, which needs the filelock package (a
dependency of jaxpose; without it there is no cache) and an access-time file beside every program
(`stamp_access_times` gives one to the programs of processes without the bound).  A cache entry that
cannot be written (a full disk) costs only the next run's compilation: JAX warns at every compilation,
which this module turns into one log line per process (`quiet_write_errors`).
"""

from __future__ import annotations

import errno
import logging
import os
import pathlib
import warnings
from collections.abc import Mapping

import jax

try:
    import filelock
except ImportError:  # JAX's eviction needs it: without it, no cache (enable_compilation_cache)
    filelock = None

log = logging.getLogger("jaxpose")

ENVIRONMENT = "JAXPOSE_COMPILATION_CACHE"
OFF = "off"
# Cache what takes this long to compile: the train and evaluation steps take seconds, and the loading
# path's many small programs add up (fractions of a second each); the rest is not worth a file.
MIN_COMPILE_TIME_S = 0.1
# Least recently used programs are deleted past this size (JAX's default is no limit at all).
MAX_SIZE_BYTES = 2 * 1024**3
# JAX's names in the folder (jax/_src/lru_cache.py): a program's file, the file of its last use that the
# eviction reads, and the lock that every process with a size limit takes (for at most 10 s, as JAX).
PROGRAM, ACCESS_TIME, LOCK_FILE, LOCK_TIMEOUT_S = "-cache", "-atime", ".lockfile", 10
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
    if filelock is None:  # a process without the size limit would write programs that break those with it
        log.warning("no compilation cache: JAX bounds its size only with the filelock package (pip install filelock)")
        return None
    # The size limit is turned on only once every program in the folder has its access-time file.  A process
    # without the limit writing the folder at the same time (JAX_COMPILATION_CACHE_DIR naming it, an earlier
    # jaxpose) can still add programs without one: this process's later writes then fail (one log line; the
    # programs are compiled again next run) and the next start stamps them.  Running without the limit
    # instead would make this process write such programs too, and the folder grow without end.
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK | os.X_OK):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))
        stamped = stamp_access_times(folder)
    except OSError as error:  # else JAX warns at every compilation
        reason = error.strerror or str(error)  # filelock's Timeout has no strerror
        log.warning("no compilation cache: %s cannot be written (%s); set %s to another folder, or to off", folder, reason, ENVIRONMENT)
        return None
    quiet_write_errors(str(folder))
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    jax.config.update("jax_compilation_cache_max_size", MAX_SIZE_BYTES)
    log.debug("persistent compilation cache in %s (%s=off to disable); %d programs written there without a size limit given"
              " their access times", folder, ENVIRONMENT, stamped)
    return str(folder)


def stamp_access_times(folder: pathlib.Path) -> int:
    """Give every program in `folder` without an access-time file one, dated when the program was written,
    under JAX's lock; returns how many.  A process without a size limit writes none, and JAX's eviction reads
    one for every program in the folder, so every write of a process with the limit fails without them."""
    with filelock.FileLock(folder / LOCK_FILE, timeout=LOCK_TIMEOUT_S):
        names = set(os.listdir(folder))
        keys = [name.removesuffix(PROGRAM) for name in names if name.endswith(PROGRAM)]
        unstamped = [key for key in keys if key + ACCESS_TIME not in names]
        for key in unstamped:
            written = (folder / (key + PROGRAM)).stat().st_mtime_ns
            (folder / (key + ACCESS_TIME)).write_bytes(written.to_bytes(8, "little"))  # JAX's format: time.time_ns()
    return len(unstamped)


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
