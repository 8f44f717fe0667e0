"""Parsed input files kept as arrays in a file the caller names (in a rig project's cache,
`jaxpose.rig.config.CACHE_DIR`: never beside the input, which is only read), reused while unchanged.

The key digests what was cached (a label that carries its version) and the input files' names and
contents (`content_digest`, BLAKE2b of every byte): a file added, removed, renamed or with other bytes, or
a cache of another kind or version, is a miss.  Contents, not sizes and modification times: a file edited
in place to the same size with its time kept (``cp -p``, ``rsync -t``, an archive extracted, ``os.utime``)
must not reuse stale data, and a folder copied without its times need not be parsed again.  The reader
hashes the bytes it parses anyway, so a first read costs no second pass (benchmarks/keypoint_files.py).
A cache that cannot be read or written is only a missed shortcut: a warning, never an error.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import warnings
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import TypeVar

import numpy as np

logger = logging.getLogger(__name__)

_Parsed = TypeVar("_Parsed")


def content_digest(data: bytes) -> bytes:
    """The digest of one input file's bytes that cache keys are made of (BLAKE2b, 128 bits)."""
    return hashlib.blake2b(data, digest_size=16).digest()


def file_digest(path: str | os.PathLike) -> bytes:
    """`content_digest` of the file `path`."""
    with open(path, "rb") as file:
        return content_digest(file.read())


def cache_key(label: str, digests: Iterable[tuple[str, bytes]]) -> str:
    """The key of a cache of `label` for input files of these (name, `content_digest`) pairs, in any order."""
    key = hashlib.sha256(f"{label}\n".encode())
    for name, digest in sorted(digests):
        key.update(os.fsencode(name) + b"\0" + digest)  # no name holds a NUL; digests have one length
    return key.hexdigest()


def load(path: Path, key: str, source: str, build: Callable[[Mapping[str, np.ndarray]], _Parsed]) -> _Parsed | None:
    """`build(arrays)` of the cache `path` of `source` where its key is `key`; None where there is none, it
    is stale, or it cannot be read (or `build` refuses its arrays, with any exception), with a warning."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                logger.info("%s changed since %s was written: reading it again", source, path)
                return None
            parsed = build(data)
    except Exception as error:  # noqa: BLE001 - any unreadable cache is only a missed shortcut
        warnings.warn(f"ignoring the unreadable cache {path} ({type(error).__name__}: {error})", stacklevel=3)
        return None
    logger.info("read %s from the cache %s", source, path)
    return parsed


def save(path: Path, key: str, source: str, arrays: Mapping[str, np.ndarray]) -> None:
    """Write `arrays` of `source` as the cache `path` with its `key`, whole or not at all (a warning)."""
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=path.name, suffix=".tmp", delete=False) as file:
            temporary = file.name
            np.savez(file, key=np.str_(key), **arrays)
        os.replace(temporary, path)
        logger.info("cached %s as %s", source, path)
    except OSError as error:
        warnings.warn(f"could not write the cache {path} ({error}); reading without it", stacklevel=3)
        if temporary is not None:
            try:
                os.unlink(temporary)
            except OSError:
                pass
