"""The per-sample arrays of a data set as one pytree, `Samples`: every field is listed once, here.

Each field is an array whose leading axis is the N samples (`labels`: a dict of such arrays), or None
where the data set has none; its declaration gives its shape after N in C views and J joints, which is
the one table that the data set's validation and `jaxpose.data.validate_batch` read.  A data set's
operations on all of its samples are then one `jax.tree.map` (a subset, a concatenation), and a new
per-sample array is one line here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax
import numpy as np


def _after_n(*shape: int | str, **default) -> dataclasses.Field:
    """A field whose arrays have `shape` after the leading N ("C": views, "J": joints)."""
    return dataclasses.field(metadata={"after_n": shape}, **default)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True, kw_only=True)  # by name: a field added later shifts no argument
class Samples:
    """N instants, C views, J joints; numpy arrays, float32 unless said otherwise."""

    keypoints2d: np.ndarray = _after_n("C", "J", 2)
    """Detected 2D, pixels."""
    confidence: np.ndarray = _after_n("C", "J")
    """Detector confidence in [0, 1]; 0 = missing joint or view."""
    rig_index: np.ndarray = _after_n()
    """i32: the sample's rig in the data set's `rigs`."""
    target3d: np.ndarray | None = _after_n("J", 3, default=None)
    """World mm ground truth, None without."""
    pseudo3d: np.ndarray | None = _after_n("J", 3, default=None)
    """World mm pseudo-labels, once `jaxpose.training.pseudo_labelling.label` has set them."""
    pseudo3d_weight: np.ndarray | None = _after_n("J", default=None)
    """The pseudo-labels' weights (see `jaxpose.data.MultiViewBatch`)."""
    detection_weight: np.ndarray | None = _after_n("C", "J", default=None)
    """Set where the pseudo-labelling rejects outlying views (see `jaxpose.data.MultiViewBatch`)."""
    labels: Mapping[str, np.ndarray] = _after_n(default_factory=dict)
    """String/int arrays such as "subject", "action", "frame" that group the evaluation's results."""
    context_row: np.ndarray | None = _after_n(default=None)
    """i32: the sample's own row in the data set's `FrameContext`; None without one."""
    context_span: np.ndarray | None = _after_n(2, default=None)
    """i32: the first and one-past-last context row of the sample's stretch of consecutive frames."""


_AFTER_N = {field.name: field.metadata["after_n"] for field in dataclasses.fields(Samples)}


def field_shape(name: str, N: int, C: int, J: int) -> tuple[int, ...]:
    """The shape of the field `name` (each array of `labels`) for N samples, C views, J joints."""
    sizes = {"C": C, "J": J}
    return (N, *(sizes.get(axis, axis) for axis in _AFTER_N[name]))


def check_shapes(samples: Samples, C: int, J: int) -> None:
    """Raise ValueError naming the first array whose shape is not its field's for C views and J joints."""
    N = len(samples.keypoints2d)
    for path, array in jax.tree_util.tree_leaves_with_path(samples):
        expected = field_shape(path[0].name, N, C, J)
        if np.shape(array) != expected:
            raise ValueError(f"{jax.tree_util.keystr(path).lstrip('.')}: expected shape {expected}, got {np.shape(array)}")

