"""The input triangulation of a data set: its pseudo-labels (paper Eq. 2), computed once before training.

    from jaxpose.training import pseudo_labelling
    from jaxpose.training.config import PseudoLabelConfig
    train = pseudo_labelling.label(train, PseudoLabelConfig(method="ransac"))

The geometry (DLT solvers, outlier rejection) is `jaxpose.robust`; this module applies it to every
sample of a `MultiViewDataset` in fixed-size chunks and stores the result in the data set.

A data set memory-mapped from .npy files (a rig project's prepared arrays, `jaxpose.rig.cache`) has
its labels kept beside them, in ``pseudo_labels/<part>-<key>/``, and memory-mapped from there by the
next run: the key digests the method and its settings, the rigs, and the detections' files (path,
size, modification and status-change times, inode: they are never rewritten in place).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import shutil
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaxpose import robust
from jaxpose.camera import projection_matrices
from jaxpose.chunks import map_over_parts
from jaxpose.training.config import PseudoLabelConfig
from jaxpose.data.dataset import MultiViewDataset


def _labels_and_agreeing_views(P, points2d, confidence, config: PseudoLabelConfig):
    """`robust.pseudo_labels` and, for the outlier-rejecting methods, the views that agree with them."""
    points, weight = robust.pseudo_labels(
        P,
        points2d,
        confidence,
        config.method,
        min_views=config.min_views,
        threshold_px=config.threshold_px,
        irls_iterations=config.irls_iterations,
        irls_scale_px=config.irls_scale_px,
    )
    if config.method not in robust.OUTLIER_REJECTING_METHODS:
        return points, weight, None
    return points, weight, robust.agreeing_views(P, points2d, confidence, points, config.threshold_px)


log = logging.getLogger(__name__)

# Module-level, so that every data set (train and test splits, repeated calls) shares its
# compilations; the config is static (a frozen dataclass hashes by value).
_solve = jax.jit(_labels_and_agreeing_views, static_argnames="config")
LABEL_CHUNK = 4096


def label(
    dataset: MultiViewDataset, config: PseudoLabelConfig = PseudoLabelConfig(), chunk_size: int = LABEL_CHUNK, progress: bool = False
) -> MultiViewDataset:
    """The data set, undistorted, with `pseudo3d` and `pseudo3d_weight` (and, for the outlier-rejecting
    methods, `detection_weight`) set from the detections of all its views.

    `config.method` and the thresholds are those of `jaxpose.robust.pseudo_labels`: "svd" (default),
    "eigh", "normal" weigh views by detector confidence, "unweighted" is the paper's plain DLT,
    "irls" and "ransac" also reject views that disagree with the others.  A joint without
    `min_views` (agreeing) views gets pseudo3d_weight 0.  So does every joint of a sample whose
    root gets 0: the pseudo-label is used root-relative, so a bad root spoils every joint.
    "irls" and "ransac" also set `detection_weight`: 0 for a detection that does not agree with
    its joint's label, so that the losses do not take an outlier as a target either.

    Chunks of exactly `chunk_size` rows (the last padded): one compilation whatever the data set's size
    (4,096 rows solve fastest per row on CPU: 0.17 ms against 0.24 at 1,024 and 0.18 at 16,384), bounded
    memory, and a memory-mapped data set read chunk by chunk.  The projection matrices are made once per
    rig and gathered per row (numpy), not computed per chunk.
    `progress`: a progress bar over the chunks; either way one timed log line.
    """
    started = time.perf_counter()
    dataset = dataset.undistorted()
    cache = _cache_folder(dataset, config)
    if cache is not None and cache.is_dir():
        # A label the method does not make (detection_weight of the plain DLT) has no file: None.
        labels = {name: np.load(cache / f"{name}.npy", mmap_mode="r") if (cache / f"{name}.npy").exists() else None for name in _STORED}
        log.info("pseudo-labels (%s) of %s instants read from %s", config.method, f"{len(dataset):,}", cache)
        return dataset.with_samples(**labels)
    size = chunk_size
    rig_matrices = np.asarray(projection_matrices(dataset.rigs))  # [R, C, 3, 4]
    bar = tqdm(total=len(dataset), desc="pseudo-labels", unit="instant", unit_scale=True, disable=not progress, leave=False)

    def solve_rows(rows, keypoints2d, confidence):
        P = rig_matrices[dataset.samples.rig_index[rows]]
        points, weight, views = jax.device_get(_solve(P, jnp.asarray(keypoints2d), jnp.asarray(confidence), config=config))
        bar.update(min(len(rows), len(dataset) - bar.n))
        weight = weight.astype(np.float32) * weight[:, :1]
        return dict(zip(_STORED, (points, weight, None if views is None else views.astype(np.float32))))

    # One chunk per part, each written into the labels as it comes: only a chunk of them is ever in
    # memory where they go to the cache (memory-mapped files), a large data set's labels never twice.
    starts = range(0, len(dataset), size)
    samples = dataset.samples
    parts = ((np.arange(start, min(start + size, len(dataset))), samples.keypoints2d[start : start + size], samples.confidence[start : start + size]) for start in starts)
    temporary = None if cache is None else _temporary_folder(cache)
    labels: dict[str, np.ndarray | None] = {}
    with bar:
        for start, chunk in zip(starts, map_over_parts(solve_rows, parts, size)):
            if not labels:
                labels = {name: None if rows is None else _allocate(temporary, name, (len(dataset), *rows.shape[1:])) for name, rows in chunk.items()}
            for name, rows in chunk.items():
                if rows is not None:
                    labels[name][start : start + len(rows)] = rows
    log.info("pseudo-labels (%s) of %s instants in %.1f s", config.method, f"{len(dataset):,}", time.perf_counter() - started)
    if temporary is not None:
        labels = _commit(temporary, cache, labels)
    return dataset.with_samples(**labels)


_STORED = ("pseudo3d", "pseudo3d_weight", "detection_weight")  # the `Samples` fields `label` sets, one cache file each
_CACHE_VERSION = 1  # bump when the labels of one method and its settings change


def _cache_folder(dataset: MultiViewDataset, config: PseudoLabelConfig) -> Path | None:
    """Where the labels of a data set whose detections are memory-mapped .npy files are kept (None otherwise)."""
    mapped = (dataset.samples.keypoints2d, dataset.samples.confidence, dataset.samples.rig_index)
    if not all(isinstance(array, np.memmap) and array.filename for array in mapped):
        return None
    key = hashlib.blake2b(repr((_CACHE_VERSION, dataclasses.asdict(config), len(dataset))).encode(), digest_size=16)
    for field in (dataset.rigs.K, dataset.rigs.R, dataset.rigs.t):
        key.update(np.ascontiguousarray(field, np.float32).tobytes())
    for array in mapped:
        status = os.stat(array.filename)
        key.update(f"{array.filename}|{array.offset}|{array.shape}|{status.st_size}|{status.st_mtime_ns}|{status.st_ctime_ns}|{status.st_ino}".encode())
    source = Path(dataset.samples.keypoints2d.filename)
    return source.parent / "pseudo_labels" / f"{source.name.split('.')[0]}-{key.hexdigest()}"


def _temporary_folder(folder: Path) -> Path | None:
    """Where the labels are written before they become `folder` (None, with a warning, if it cannot be made)."""
    temporary = folder.with_name(f"{folder.name}.tmp-{os.getpid()}")
    try:
        temporary.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        log.warning("the pseudo-labels are not cached (%s cannot be written: %s)", folder, error)
        return None
    return temporary


def _allocate(temporary: Path | None, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """The float32 array of one label: a memory-mapped .npy file in `temporary`, or in memory."""
    if temporary is None:
        return np.empty(shape, np.float32)
    return np.lib.format.open_memmap(temporary / f"{name}.npy", mode="w+", dtype=np.float32, shape=shape)


def _commit(temporary: Path, folder: Path, labels: dict[str, np.ndarray | None]) -> dict[str, np.ndarray | None]:
    """The labels written in `temporary` made `folder` (whole or not at all) and memory-mapped read-only
    from it; another process that finished first leaves its own."""
    for array in labels.values():
        if array is not None:
            array.flush()
    try:
        os.rename(temporary, folder)
        log.info("pseudo-labels written to %s", folder)
    except OSError:
        shutil.rmtree(temporary, ignore_errors=True)
        if not folder.is_dir():
            raise
    return {name: None if array is None else np.load(folder / f"{name}.npy", mmap_mode="r") for name, array in labels.items()}
