"""Work on many small files (parsing, hashing) in chunks, by a process pool where that pays.

Workers are forked where the platform has it: they start in milliseconds and run json, hashlib and
numpy only, so a parent's JAX threads do not matter.  Elsewhere (macOS, Windows) they are spawned and
import jax again, so a pool pays only from more files.  A task reports a bad file as a tuple
("error", where, expected, found), since `DataFormatError` does not pickle; `map_chunks` raises it.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import warnings
from collections.abc import Callable, Sequence
from typing import Any

from tqdm.auto import tqdm

from jaxpose.formats.errors import DataFormatError

CHUNK_FILES = 256
"""Files per pool task."""
POOL_MIN_FILES = 2000
"""Below this many files one process does them all: starting a pool does not pay."""
POOL_MIN_FILES_SPAWN = 20000
"""The same where workers are spawned (not forked) and must import jax again (macOS, Windows)."""


def pool_context() -> tuple[Any, int]:
    """(the multiprocessing context, the fewest files a pool is started for): fork where the platform
    has it, else the default start method with the higher threshold."""
    if "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork"), POOL_MIN_FILES
    return None, POOL_MIN_FILES_SPAWN


def map_chunks(
    function: Callable[[Sequence[str]], tuple], paths: Sequence[str], desc: str, progress: bool, workers: int | None
) -> list[tuple]:
    """`function` of each chunk of `CHUNK_FILES` paths, its results without their "ok", in order.

    `workers` processes (default ``os.cpu_count()``) where there are enough files to pay for a pool,
    else this one; a tqdm bar `desc` with `progress`.  The first ("error", where, expected, found)
    result raises its `DataFormatError`.
    """
    chunks = [paths[i : i + CHUNK_FILES] for i in range(0, len(paths), CHUNK_FILES)]
    context, threshold = pool_context()
    workers = min(workers or os.cpu_count() or 1, len(chunks))
    parts, executor = [], None
    try:
        if workers > 1 and len(paths) >= threshold:
            executor = concurrent.futures.ProcessPoolExecutor(workers, mp_context=context)
            with warnings.catch_warnings():  # the workers fork at the first submit, inside map
                # JAX (when the caller started it) warns at every fork; these workers never touch JAX.
                for category in (RuntimeWarning, DeprecationWarning):
                    warnings.filterwarnings("ignore", r".*(os\.fork|use of fork)", category)
                results = executor.map(function, chunks)
        else:
            results = map(function, chunks)
        with tqdm(total=len(paths), desc=desc, unit="file", disable=not progress, delay=0.5) as bar:
            for chunk, result in zip(chunks, results):
                if result[0] == "error":
                    raise DataFormatError(*result[1:])
                parts.append(result[1:])
                bar.update(len(chunk))
    finally:
        if executor is not None:
            executor.shutdown(wait=True, cancel_futures=True)
    return parts
