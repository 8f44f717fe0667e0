"""One wild keypoint must not ruin a pose (issue 26): the median input normalisation, the detector-failure
augmentation of the train step, and the missing-keypoint policy of `Lifter3D.predict`, `jaxpose.predict`
and the exported forms."""

from __future__ import annotations

import dataclasses
import json

import chex
import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import onnxruntime
import pytest
from geometry_helpers import exact_batch, random_poses, random_rig
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose import export, predict

from jaxpose.serving import inference
from jaxpose.camera import MEDIAN_RADIUS_LIMIT, masked_median, normalize_keypoints, project
from jaxpose.training.config import InputAugmentation, LossConfig, OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.skeleton import H36M_17
from jaxpose.model import make_eval_step
from jaxpose.training.step import augment_inputs, init_train_state, make_train_step

IMAGE = (1000.0, 1000.0)


@given(
    hnp.arrays(np.float32, 20, elements=st.floats(-1e3, 1e3, width=32)),
    hnp.arrays(np.bool_, 20),
)
def test_masked_median_is_numpys_median_of_the_valid_entries(values, valid):
    # One length (one compilation): any shorter array is this one with the rest invalid.
    got = float(masked_median(jnp.asarray(values), jnp.asarray(valid)))
    expected = float(np.median(values[valid].astype(np.float64))) if valid.any() else 0.0
    assert got == pytest.approx(expected, rel=1e-6, abs=1e-6)


def _one_view(seed: int):
    rng = np.random.default_rng(seed)
    cameras = random_rig(rng, 4)
    pose = jnp.asarray(random_poses(rng, 1, 17))
    return np.array(project(cameras, pose)), np.array(cameras.K)


def test_median_normalisation_is_camera_and_distance_invariant_with_unit_median():
    pixels, K = _one_view(7)
    near = np.asarray(normalize_keypoints(pixels, K, mode="intrinsics_median"))
    K2 = K.copy()
    K2[:, :2, :2] *= 1.5
    K2[:, 0, 2] += 40.0
    moved = pixels.copy()
    moved = (moved - K[:, None, :2, 2]) * 1.5 + K2[:, None, :2, 2]  # the same rays through the other camera
    np.testing.assert_allclose(normalize_keypoints(moved, K2, mode="intrinsics_median"), near, atol=1e-4)
    assert np.allclose(near[:, 0], 0.0)
    np.testing.assert_allclose(np.median(np.linalg.norm(near[:, 1:], axis=-1), axis=-1), 1.0, rtol=1e-5)
    confidence = np.ones((4, 17), np.float32)
    confidence[1, 5], confidence[2, 0] = 0.0, 0.0
    pixels[1, 5] = np.nan
    masked = np.asarray(normalize_keypoints(pixels, K, confidence, "intrinsics_median"))
    assert np.isfinite(masked).all() and np.all(masked[1, 5] == 0) and np.all(masked[2] == 0)


@given(
    seed=st.integers(0, 2**16),
    joint=st.integers(1, 16),
    offset=st.tuples(st.floats(-1e5, 1e5), st.floats(-1e5, 1e5)),
)
def test_one_joint_moved_anywhere_barely_changes_the_others_inputs(seed, joint, offset):
    """The median of the other 15 distances brackets the new median (it moves by at most one rank), so
    every other joint's input is scaled by a factor between the neighbouring order statistics' ratios;
    the moved joint itself stays within MEDIAN_RADIUS_LIMIT.  The RMS scale has no such bound."""
    pixels, K = _one_view(seed)
    pixels, K = pixels[:1], K[:1]
    moved = pixels.copy()
    moved[0, joint] += np.asarray(offset, np.float32)
    before = np.asarray(normalize_keypoints(pixels, K, mode="intrinsics_median"))[0]
    after = np.asarray(normalize_keypoints(moved, K, mode="intrinsics_median"))[0]
    relative = np.asarray(normalize_keypoints(pixels, K, mode="intrinsics"))[0]
    distances = np.linalg.norm(relative[1:], axis=-1)
    order = np.sort(np.delete(distances, joint - 1))  # the other 15, sorted
    median = np.median(distances)
    low, high = order[6] / median, order[8] / median  # the new median lies in [order[6], order[8]]
    others = [j for j in range(1, 17) if j != joint]
    radius_before = np.linalg.norm(before[others], axis=-1)
    radius_after = np.linalg.norm(after[others], axis=-1)
    clamped = radius_before >= MEDIAN_RADIUS_LIMIT * 0.999
    ratio = radius_after[~clamped] / radius_before[~clamped]
    assert np.all(ratio >= 1 / high - 1e-4) and np.all(ratio <= 1 / low + 1e-4)
    assert np.linalg.norm(after[joint]) <= MEDIAN_RADIUS_LIMIT + 1e-4
    # Directions of the other joints do not change at all.
    unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(unit(after[others]), unit(before[others]), atol=1e-4)


def test_augmentation_touches_one_joint_per_view_pose_never_the_root_and_is_a_function_of_the_key():
    rng = np.random.default_rng(0)
    keypoints = jnp.asarray(rng.uniform(200, 800, (256, 4, 16, 2)), jnp.float32)
    confidence = jnp.ones((256, 4, 16))
    pairs = ((1, 4), (2, 5), (3, 6))
    none = augment_inputs(jax.random.key(1), keypoints, confidence, InputAugmentation(), pairs)
    chex.assert_trees_all_equal(none, (keypoints, confidence))
    drop = augment_inputs(jax.random.key(1), keypoints, confidence, InputAugmentation(drop=1.0), pairs)
    assert np.all((np.asarray(drop[1]) == 0).sum(-1) == 1) and np.all(np.asarray(drop[1])[..., 0] == 1)
    shifted = augment_inputs(jax.random.key(1), keypoints, confidence, InputAugmentation(displace=1.0), pairs)
    changed = (np.asarray(shifted[0]) != np.asarray(keypoints)).any(-1)
    assert changed.sum(-1).max() == 1 and not changed[..., 0].any() and changed.mean() > 0.9 / 15
    swapped = augment_inputs(jax.random.key(1), keypoints, confidence, InputAugmentation(swap=1.0), pairs)
    changed = (np.asarray(swapped[0]) != np.asarray(keypoints)).any(-1)
    assert np.all(changed.sum(-1) == 2)
    same = np.sort(np.asarray(swapped[0]).reshape(-1, 16, 2), axis=1)
    np.testing.assert_array_equal(same, np.sort(np.asarray(keypoints).reshape(-1, 16, 2), axis=1))
    mixed = InputAugmentation(drop=0.2, displace=0.2, swap=0.2)
    a = augment_inputs(jax.random.key(3), keypoints, confidence, mixed, pairs)
    b = augment_inputs(jax.random.key(3), keypoints, confidence, mixed, pairs)
    c = augment_inputs(jax.random.key(4), keypoints, confidence, mixed, pairs)
    chex.assert_trees_all_equal(a, b)
    assert not np.array_equal(np.asarray(a[0]), np.asarray(c[0]))
    with pytest.raises(ValueError, match="<= 1"):
        InputAugmentation(drop=0.6, displace=0.6)


def test_augmented_train_step_is_reproducible_and_off_means_unchanged():
    batch, _ = exact_batch(np.random.default_rng(3), 8, 4, 17)
    config = ModelConfig(width=64, input_normalization="intrinsics_median")
    model = config.build(17)
    optimizer = OptimizerConfig().build(10)
    state = init_train_state(model, optimizer, jax.random.key(0))

    def step(augmentation):
        return jax.jit(make_train_step(model, config, optimizer, LossConfig(), 10, augmentation=augmentation, skeleton=H36M_17))

    plain = step(InputAugmentation())(state, batch, jax.random.key(5))[0]
    default = jax.jit(make_train_step(model, config, optimizer, LossConfig(), 10))(state, batch, jax.random.key(5))[0]
    chex.assert_trees_all_equal(plain.params, default.params)
    augmented = step(InputAugmentation(drop=0.3, displace=0.3, swap=0.3))
    a, b = augmented(state, batch, jax.random.key(5))[0], augmented(state, batch, jax.random.key(5))[0]
    chex.assert_trees_all_equal(a.params, b.params)
    assert not np.array_equal(np.asarray(a.params["Dense_0"]["kernel"]), np.asarray(plain.params["Dense_0"]["kernel"]))


@pytest.fixture(scope="module")
def median_lifter(lifter):
    """The shared tiny lifter's weights behind the median normalisation."""
    config = dataclasses.replace(lifter.model_config, input_normalization="intrinsics_median")
    return dataclasses.replace(lifter, model_config=config, eval_step=make_eval_step(config.build(lifter.num_joints), config))


def _test_poses(test, count):
    N, C, J, _ = test.samples.keypoints2d.shape
    keypoints = test.samples.keypoints2d.reshape(N * C, J, 2)[:count].copy()
    K = np.asarray(test.rigs.K)[test.samples.rig_index].reshape(N * C, 3, 3)[:count].astype(np.float32)
    return keypoints, K


@given(
    pose=st.integers(0, 15),
    joint=st.integers(1, 16),
    side=st.integers(0, 3),
    beyond=st.floats(101.0, 1e6),
    along=st.floats(-1e6, 1e6),
)
def test_a_joint_anywhere_outside_the_image_is_missing_in_predict(trained_run, median_lifter, pose, joint, side, beyond, along):
    """Beyond the margin (10% of 1000 px) a joint is lifted as missing: exactly the prediction with that
    joint's confidence 0, wherever it is, so the change of the other joints is that of one missing joint."""
    keypoints, K = _test_poses(trained_run[1], 16)
    keypoints, K = keypoints[pose : pose + 1], K[pose : pose + 1]
    place = [(-beyond, along), (IMAGE[0] + beyond, along), (along, -beyond), (along, IMAGE[1] + beyond)][side]
    moved = keypoints.copy()
    moved[0, joint] = place
    missing = np.ones((1, 17), np.float32)
    missing[0, joint] = 0.0
    options = dict(image_size=IMAGE, outside_margin=0.1)
    lifted = median_lifter.predict(moved, K, **options)
    np.testing.assert_array_equal(lifted, median_lifter.predict(keypoints, K, missing, **options))


def test_predict_min_confidence_and_implausible_joints():
    keypoints = np.full((3, 4, 2), 500.0, np.float32)
    confidence = np.ones((3, 4), np.float32)
    keypoints[0, 1] = np.nan
    keypoints[1, 2] = (-101.0, 500.0)
    keypoints[2, 3] = (1099.0, 500.0)  # within the margin: kept
    confidence[2, 1] = 0.04
    confidence[2, 2] = 0.0
    keypoints[2, 2] = np.inf  # missing already: not counted
    found = inference.implausible_joints(keypoints, confidence, IMAGE, 0.1, 0.05)
    assert np.argwhere(found["non_finite"]).tolist() == [[0, 1]]
    assert np.argwhere(found["outside_image"]).tolist() == [[1, 2]]
    assert np.argwhere(found["low_confidence"]).tolist() == [[2, 1]]
    assert not inference.implausible_joints(keypoints, confidence, None, 0.1, 0.0)["outside_image"].any()
    # A NaN score is no score: missing, and counted as non-finite (not an error, not a detection).
    confidence[1, 3] = np.nan
    assert np.argwhere(inference.implausible_joints(keypoints, confidence, IMAGE, 0.1, 0.05)["non_finite"]).tolist() == [[0, 1], [1, 3]]
    with pytest.raises(ValueError, match=r"confidence: expected shape \(3, 4\)"):
        inference.implausible_joints(keypoints, confidence[:, :1], IMAGE)


def test_cli_reports_nan_low_and_outside_keypoints_per_reason(trained_run, lifter, tmp_path, capsys):
    """A COCO detection whose nose is NaN with score 0.9 is lifted with the nose missing, and said so."""
    test = trained_run[1]
    keypoints, K = _test_poses(test, 4)
    entries = []
    coco = np.zeros((4, 17, 3), np.float64)
    # Place COCO-17 keypoints from the test poses: hips, knees, ankles, shoulders, elbows, wrists, nose.
    order = {11: 4, 12: 1, 13: 5, 14: 2, 15: 6, 16: 3, 5: 11, 6: 14, 7: 12, 8: 15, 9: 13, 10: 16, 0: 9}
    for coco_joint, ours in order.items():
        coco[:, coco_joint, :2] = keypoints[:, ours]
    coco[:, 1:5, :2] = keypoints[:, 10:11]  # eyes and ears at the head
    coco[..., 2] = 0.9
    coco[0, 0, :2] = np.nan  # the nose: NaN with score 0.9
    coco[1, 9, :2] = (-5000.0, 20.0)  # a wrist far outside
    coco[2, 10, 2] = 0.01  # a wrist below --min-confidence
    for i in range(4):
        entries.append({"image_id": i, "category_id": 1, "keypoints": coco[i].ravel().tolist(), "score": 0.9})
    path = tmp_path / "detections.json"
    path.write_text(json.dumps(entries))
    fx, fy, cx, cy = K[0, 0, 0], K[0, 1, 1], K[0, 0, 2], K[0, 1, 2]
    common = ["--checkpoint", str(trained_run[0]), "--input", str(path), "--intrinsics", str(fx), str(fy), str(cx), str(cy)]
    poses = predict.main([*common, "--output", str(tmp_path / "out.npz"), "--image-size", "1000", "1000"])
    err = capsys.readouterr().err
    assert "treated 3 joints of 3 of 4 poses as missing" in err
    assert "1 joint of 1 pose: NaN or infinite coordinates with a positive score, or a NaN or infinite score (first: pose 0, nose" in err
    assert "1 joint of 1 pose: score below --min-confidence 0.05 (first: pose 2, right_wrist" in err
    assert "1 joint of 1 pose: more than --outside-margin 0.1" in err and "first: pose 1, left_wrist" in err
    assert np.isfinite(poses).all()
    # Without an image size the outside-image check cannot be made, and the report says so.
    predict.main([*common, "--output", str(tmp_path / "out2.npz"), "--min-confidence", "0"])
    err = capsys.readouterr().err
    assert "treated 1 joint of 1 of 4 poses as missing" in err and "pass --image-size" in err


@pytest.mark.parametrize("form", ["jax", "onnx"])
def test_exported_forms_use_the_median_normalisation(trained_run, median_lifter, tmp_path, form):
    keypoints, K = _test_poses(trained_run[1], 9)
    confidence = np.ones(keypoints.shape[:2], np.float32)
    keypoints[3, 7] = (1e5, -1e5)  # a wild joint: the RMS scale would shrink the others, the median does not
    expected = median_lifter.predict(keypoints, K, confidence)
    if form == "jax":
        path = export.export_jax(median_lifter, tmp_path / "lifter.jax_export")
        poses = np.asarray(jax.export.deserialize(path.read_bytes()).call(keypoints, K, confidence))
    else:
        path = export.export_onnx(median_lifter, tmp_path / "lifter.onnx")
        (poses,) = onnxruntime.InferenceSession(str(path)).run(None, {"keypoints": keypoints, "K": K, "confidence": confidence})
    np.testing.assert_allclose(poses, expected, atol=0.01, rtol=0)
    rms = dataclasses.replace(median_lifter.model_config, input_normalization="intrinsics_scale")
    other = make_eval_step(rms.build(median_lifter.num_joints), rms)(median_lifter.variables, keypoints, K, confidence)
    assert np.abs(np.asarray(other)[3] - expected[3]).max() > 1.0  # the forms would tell the two apart


def test_leave_one_out_residuals_match_a_numpy_oracle(trained_run, lifter):
    """Each joint lifted as missing by `predict`, the lifted (x, y) and the detected pose both divided by
    their median joint-to-root distance over the other given joints: the residual is their distance."""
    keypoints, K = _test_poses(trained_run[1], 6)
    confidence = np.ones(keypoints.shape[:2], np.float32)
    confidence[2, 7] = 0.0  # a missing joint: residual 0, and out of every median
    J = keypoints.shape[1]
    got = np.asarray(inference.leave_one_out_residuals(lifter.eval_step, lifter.variables, keypoints, K, confidence))
    rays = np.einsum("nij,nkj->nki", np.linalg.inv(K.astype(np.float64)), np.concatenate([keypoints, np.ones((6, J, 1))], -1))
    detected = rays[..., :2] / rays[..., 2:] - (rays[..., :2] / rays[..., 2:])[:, :1]
    expected = np.zeros((6, J))
    for j in range(1, J):
        without = confidence.copy()
        without[:, j] = 0.0
        lifted = lifter.predict(keypoints, K, without)[..., :2].astype(np.float64)
        for n in range(6):
            if confidence[n, j] == 0:
                continue
            others = (without[n] > 0) & (np.arange(J) > 0)
            a = detected[n, j] / np.median(np.linalg.norm(detected[n, others], axis=-1))
            b = lifted[n, j] / np.median(np.linalg.norm(lifted[n, others], axis=-1))
            expected[n, j] = np.linalg.norm(a - b)
    np.testing.assert_allclose(got, expected, atol=2e-3)
    assert got[2, 7] == 0.0 and (got[:, 0] == 0).all()


def test_residuals_need_the_root_and_three_other_joints_and_chunks_change_nothing(trained_run, lifter):
    keypoints, K = _test_poses(trained_run[1], 5)
    confidence = np.ones(keypoints.shape[:2], np.float32)
    confidence[1, 0] = 0.0  # no root: nothing is measurable
    confidence[2, 4:] = 0.0  # the root and 3 joints: each left out has 2 others, whose median says nothing
    got = np.asarray(inference.leave_one_out_residuals(lifter.eval_step, lifter.variables, keypoints, K, confidence))
    assert (got[1] == 0).all() and (got[2] == 0).all() and (got[[0, 3, 4], 1:] > 0).all()
    rejected = lifter.inconsistent_joints(lifter.prepare(keypoints, K, confidence), threshold=0.5)
    assert rejected.any() and not rejected[[1, 2]].any()
    one_per_call = dataclasses.replace(lifter, batch_size=lifter.num_joints)
    np.testing.assert_array_equal(one_per_call.inconsistent_joints(one_per_call.prepare(keypoints, K, confidence), threshold=0.5), rejected)
    np.testing.assert_array_equal(lifter.inconsistent_joints(lifter.prepare(keypoints[3], K[3]), threshold=0.5), rejected[3:4])
    with pytest.raises(ValueError, match=r"reject_inconsistent \(the residual threshold\) must be > 0"):
        lifter.inconsistent_joints(lifter.prepare(keypoints, K), threshold=0.0)


def _lifter_that_knows(lifter, pose_in_camera: np.ndarray):
    """`lifter` with its network replaced by one that returns this root-relative pose for every input."""
    pose = jnp.asarray(pose_in_camera - pose_in_camera[:1])

    def eval_step(variables, keypoints, K, confidence):
        return jnp.broadcast_to(pose, (keypoints.shape[0], *pose.shape))

    return dataclasses.replace(lifter, eval_step=eval_step)


@given(
    seed=st.integers(0, 2**16),
    joint=st.integers(1, 16),
    angle=st.floats(0.0, 2 * np.pi),
    far=st.floats(4.0, 50.0),
)
@settings(max_examples=10)  # each example compiles its own network
def test_with_a_lifter_that_knows_the_pose_exactly_the_moved_joint_is_rejected(lifter, seed, joint, angle, far):
    """A body 6 m away fits its weak-perspective image to within 1 median distance (clean: nothing is
    rejected).  One joint moved by `far` >= 4 median distances lies >= 3 from where the rest puts it, and
    moves every other joint's residual by at most the one-rank change of their median: it alone is
    rejected, and `predict` lifts the pose as with the rejected joint missing."""
    rng = np.random.default_rng(seed)
    body = random_poses(rng, 1, 17)[0].astype(np.float64)
    body = body - body.mean(0) + np.array([0.0, 0.0, 6000.0])
    K = np.array([[1000.0, 0.0, 500.0], [0.0, 1000.0, 500.0], [0.0, 0.0, 1.0]], np.float32)
    keypoints = (body[:, :2] / body[:, 2:] * 1000.0 + 500.0).astype(np.float32)[None]
    knows = _lifter_that_knows(lifter, body.astype(np.float32))
    assert not knows.inconsistent_joints(knows.prepare(keypoints, K), threshold=1.0).any()
    median = np.median(np.linalg.norm(keypoints[0, 1:] - keypoints[0, :1], axis=-1))
    moved = keypoints.copy()
    moved[0, joint] += far * median * np.array([np.cos(angle), np.sin(angle)], np.float32)
    rejected = knows.inconsistent_joints(knows.prepare(moved, K), threshold=inference.DEFAULT_INCONSISTENT_RESIDUAL)
    assert np.argwhere(rejected).tolist() == [[0, joint]]
    # `predict` lifts the joints `inconsistent_joints` finds as missing (here with the shared tiny lifter).
    rejected = lifter.inconsistent_joints(lifter.prepare(moved, K))
    np.testing.assert_array_equal(
        lifter.predict(moved, K, reject_inconsistent=inference.DEFAULT_INCONSISTENT_RESIDUAL),
        lifter.predict(moved, K, np.where(rejected, 0.0, 1.0).astype(np.float32)),
    )


def test_cli_rejects_inconsistent_joints_and_says_how_many(trained_run, lifter, tmp_path, capsys):
    keypoints, K = _test_poses(trained_run[1], 8)
    keypoints[3, 12] += (400.0, -300.0)  # a wrist far from where the rest of the pose puts it
    path = tmp_path / "poses.npz"
    np.savez(path, keypoints=keypoints, K=K)
    common = ["--checkpoint", str(trained_run[0]), "--input", str(path), "--min-confidence", "0"]
    poses = predict.main([*common, "--output", str(tmp_path / "out.npz"), "--reject-inconsistent", "1.0"])
    rejected = lifter.inconsistent_joints(lifter.prepare(keypoints, K), threshold=1.0)
    assert rejected[3, 12]
    np.testing.assert_array_equal(poses, lifter.predict(keypoints, K, reject_inconsistent=1.0))
    noun = "joint" if rejected.sum() == 1 else "joints"
    assert f"lifted {int(rejected.sum())} {noun} as missing (at most one per pose)" in capsys.readouterr().err
    # Off by default: every given joint is lifted as given.
    np.testing.assert_array_equal(predict.main([*common, "--output", str(tmp_path / "plain.npz")]), lifter.predict(keypoints, K))
    assert "--reject-inconsistent" not in capsys.readouterr().err
