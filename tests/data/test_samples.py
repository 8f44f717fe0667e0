"""The per-sample arrays as one pytree (`jaxpose.data.samples.Samples`): the one table of their shapes that
the validation reads, and a data set's subset and concatenation over every field at once."""

import dataclasses

import jax
import numpy as np
import pytest

from jaxpose.camera import Cameras
from jaxpose.data import MultiViewDataset, Samples
from jaxpose.data.dataset import concatenate
from jaxpose.data.samples import field_shape
from jaxpose.skeleton import H36M_17

N, C, J = 6, 2, H36M_17.num_joints


def _dataset() -> MultiViewDataset:
    rng = np.random.default_rng(0)
    samples = Samples(
        keypoints2d=rng.uniform(0, 1000, (N, C, J, 2)).astype(np.float32),
        confidence=rng.uniform(0, 1, (N, C, J)).astype(np.float32),
        rig_index=np.zeros(N, np.int32),
        target3d=rng.normal(size=(N, J, 3)).astype(np.float32),
        labels={"subject": np.array(["S1"] * 3 + ["S2"] * 3), "frame": np.arange(N)},
    )
    rigs = Cameras(K=np.tile(np.eye(3, dtype=np.float32), (1, C, 1, 1)), R=np.tile(np.eye(3, dtype=np.float32), (1, C, 1, 1)),
                   t=np.zeros((1, C, 3), np.float32))  # fmt: skip
    return MultiViewDataset(H36M_17, rigs, samples).with_own_context()


def test_a_subset_takes_its_rows_of_every_array_and_every_row_is_the_data_set_itself():
    dataset = _dataset()
    assert dataset.subset(np.arange(N)) is dataset  # no copy: a memory-mapped data set stays on disk
    rows = np.array([4, 1])
    part = dataset.subset(rows)
    jax.tree.map(lambda got, whole: np.testing.assert_array_equal(got, whole[rows]), part.samples, dataset.samples)
    assert part.samples.labels["subject"].tolist() == ["S2", "S1"] and part.context is dataset.context


def test_concatenated_parts_are_the_whole_and_parts_must_have_the_same_fields():
    dataset = _dataset()
    first, second = dataset.subset(np.arange(3)), dataset.subset(np.arange(3, N))
    joined = concatenate([first, second])
    jax.tree.map(np.testing.assert_array_equal, joined.samples, dataset.samples)
    np.testing.assert_array_equal(joined.windows(np.arange(N), 3)[0], dataset.windows(np.arange(N), 3)[0])
    with pytest.raises(ValueError, match="differ in target3d"):
        concatenate([first, second.with_samples(target3d=None)])
    with pytest.raises(ValueError, match="differ in labels"):
        concatenate([first, second.with_samples(labels={"subject": second.samples.labels["subject"]})])


@pytest.mark.parametrize("field", [field.name for field in dataclasses.fields(Samples) if field.name not in ("keypoints2d", "labels")])
def test_every_field_is_checked_against_its_shape_in_the_table(field):
    dataset = _dataset()
    expected = field_shape(field, N, C, J)
    wrong = np.zeros((N + 1, *expected[1:]), np.float32)
    with pytest.raises(ValueError, match=rf"^{field}: expected shape \({N},"):
        MultiViewDataset(dataset.skeleton, dataset.rigs, dataclasses.replace(dataset.samples, **{field: wrong}), dataset.context)


def test_every_label_has_one_entry_per_sample():
    dataset = _dataset()
    labels = {"subject": dataset.samples.labels["subject"], "frame": np.arange(N + 1)}
    with pytest.raises(ValueError, match=r"^labels\['frame'\]: expected shape \(6,\), got \(7,\)"):
        dataset.with_samples(labels=labels)
