"""The input triangulation of a data set: its pseudo-labels (paper Eq. 2), computed once before training.

    from jaxpose import pseudo_labelling
    from jaxpose.config import PseudoLabelConfig
    train = pseudo_labelling.label(train, PseudoLabelConfig(method="ransac"))

The geometry (DLT solvers, outlier rejection) is `jaxpose.robust`; this module applies it to every
sample of a `MultiViewDataset` in fixed-size chunks and stores the result in the data set.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaxpose import robust
from jaxpose.camera import projection_matrices
from jaxpose.chunks import chunk_rows, map_in_chunks
from jaxpose.config import PseudoLabelConfig
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


def label(
    dataset: MultiViewDataset, config: PseudoLabelConfig = PseudoLabelConfig(), chunk_size: int = 16384, progress: bool = False
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

    Chunks of `jaxpose.chunks.chunk_rows` rows (at most `chunk_size`): a few compilations whatever
    the data set's size, bounded memory, and a memory-mapped data set read chunk by chunk.
    `progress`: a progress bar over the chunks; either way one timed log line.
    """
    started = time.perf_counter()
    dataset = dataset.undistorted()
    size = chunk_rows(len(dataset), chunk_size)
    bar = tqdm(total=len(dataset), desc="pseudo-labels", unit="instant", unit_scale=True, disable=not progress, leave=False)

    def solve_rows(rows, keypoints2d, confidence):
        P = projection_matrices(dataset.cameras_for(rows))
        points, weight, views = jax.device_get(_solve(P, jnp.asarray(keypoints2d), jnp.asarray(confidence), config=config))
        bar.update(min(len(rows), len(dataset) - bar.n))
        # As stored, chunk by chunk: no second copy of the whole data set's labels.
        weight = weight.astype(np.float32) * weight[:, :1]
        return points, weight, None if views is None else views.astype(np.float32)

    with bar:
        pseudo3d, weight, agreeing = map_in_chunks(solve_rows, (np.arange(len(dataset)), dataset.keypoints2d, dataset.confidence), size)
    log.info("pseudo-labels (%s) of %s instants in %.1f s", config.method, f"{len(dataset):,}", time.perf_counter() - started)
    return dataclasses.replace(dataset, pseudo3d=pseudo3d, pseudo3d_weight=weight, detection_weight=agreeing)
