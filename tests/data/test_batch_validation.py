"""validate_batch: every kind of bad input ends in a clear error naming field, shape and index."""

import re

import jax.numpy as jnp
import numpy as np
import pytest
from geometry_helpers import exact_batch
from hypothesis import given
from hypothesis import strategies as st

from jaxpose.data import BatchValidationError, validate_batch


@pytest.fixture(scope="module")
def good():
    batch, _ = exact_batch(np.random.default_rng(0), 4, 4, 17)
    return batch


def test_good_batch_passes(good):
    validate_batch(good)


@given(
    field=st.sampled_from(["keypoints2d", "confidence", "pseudo3d"]),
    value=st.sampled_from([np.nan, np.inf, -np.inf]),
    seed=st.integers(0, 10_000),
)
def test_non_finite_values_are_named(good, field, value, seed):
    array = np.array(getattr(good, field))
    index = tuple(int(np.random.default_rng(seed).integers(n)) for n in array.shape)
    array[index] = value
    with pytest.raises(BatchValidationError, match=rf"{field}: .*non-finite.*index {re.escape(str(index))}"):
        validate_batch(good.replace(**{field: jnp.asarray(array)}))





def test_wrong_shapes_and_dtypes(good):
    with pytest.raises(BatchValidationError, match=r"confidence: expected shape \(4, 4, 17\), got \(4, 4, 16\)"):
        validate_batch(good.replace(confidence=good.confidence[..., :16]))
    with pytest.raises(BatchValidationError, match=r"pseudo3d: expected shape"):
        validate_batch(good.replace(pseudo3d=good.pseudo3d[:, :, :2]))
    with pytest.raises(BatchValidationError, match=r"keypoints2d: expected a floating dtype, got int32"):
        validate_batch(good.replace(keypoints2d=good.keypoints2d.astype(jnp.int32)))
    with pytest.raises(BatchValidationError, match=r"cameras.K: expected shape"):
        validate_batch(good.replace(cameras=good.cameras.replace(K=good.cameras.K[:, :3])))


def test_too_few_views(good):
    confidence = good.confidence.at[2, 1:, 0].set(0.0)  # sample 2: only view 0 has a root
    with pytest.raises(BatchValidationError, match="sample 2 has 1 usable views"):
        validate_batch(good.replace(confidence=confidence))
    single, _ = exact_batch(np.random.default_rng(1), 2, 2, 17)
    with pytest.raises(BatchValidationError, match="need at least 3"):
        validate_batch(single, min_views=3)


def test_confidence_out_of_range(good):
    with pytest.raises(BatchValidationError, match=r"confidence: values must lie in \[0, 1\]"):
        validate_batch(good.replace(confidence=good.confidence.at[0, 0, 3].set(1.5)))


def test_degenerate_cameras(good):
    cameras = good.cameras
    with pytest.raises(BatchValidationError, match=r"cameras.K: non-positive focal length at index \(1, 2\)"):
        validate_batch(good.replace(cameras=cameras.replace(K=cameras.K.at[1, 2, 0, 0].set(0.0))))
    with pytest.raises(BatchValidationError, match=r"cameras.R: not a rotation"):
        validate_batch(good.replace(cameras=cameras.replace(R=cameras.R.at[0, 1].multiply(2.0))))
    with pytest.raises(BatchValidationError, match=r"cameras.R: not a rotation"):
        validate_batch(good.replace(cameras=cameras.replace(R=-cameras.R)))  # det -1: a reflection
    same_centre = cameras.replace(R=cameras.R.at[:, 1].set(cameras.R[:, 0]), t=cameras.t.at[:, 1].set(cameras.t[:, 0]))
    with pytest.raises(BatchValidationError, match="share one camera centre"):
        validate_batch(good.replace(cameras=same_centre))
    with pytest.raises(BatchValidationError, match="cameras.t: .*non-finite"):
        validate_batch(good.replace(cameras=cameras.replace(t=cameras.t.at[3, 3, 1].set(np.nan))))


def test_subject_behind_a_camera(good):
    # Move the subject behind camera 0 of sample 0: along -z of that camera.
    R, t = np.asarray(good.cameras.R[0, 0]), np.asarray(good.cameras.t[0, 0])
    centre = -R.T @ t
    behind = centre - 2000.0 * R[2]
    pseudo3d = good.pseudo3d.at[0].set(good.pseudo3d[0] - good.pseudo3d[0, :1] + behind)
    with pytest.raises(BatchValidationError, match="behind camera 0"):
        validate_batch(good.replace(pseudo3d=pseudo3d))
