"""Multi-view data: the batch contract and the in-memory data set (the loaders are in `jaxpose.datasets` and `jaxpose.rig`)."""

from jaxpose.data.batch import BatchValidationError, MultiViewBatch, validate_batch, validate_cameras
from jaxpose.data.dataset import (
    MultiViewDataset,
    epoch_order,
    steps_per_epoch,
    training_indices,
)
from jaxpose.data.samples import Samples

__all__ = [
    "BatchValidationError",
    "MultiViewBatch",
    "MultiViewDataset",
    "Samples",
    "epoch_order",
    "steps_per_epoch",
    "training_indices",
    "validate_batch",
    "validate_cameras",
]
