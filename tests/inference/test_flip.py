"""Test-time flip augmentation (`jaxpose.flip`): geometric identities of the mirror, the flip-averaged
lifter's equivariance, and the flip in `Lifter3D.predict` and in both exported forms."""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import export, predict
from jaxpose.camera import INPUT_NORMALIZATIONS, normalize_keypoints
from jaxpose.model import ModelConfig
from jaxpose.flip import flip_averaged, mirror_input, mirror_pose3d
from jaxpose.serving.inference import Lifter3D
from jaxpose.skeleton import H36M_17
from jaxpose.model import make_eval_step

# A camera whose principal point is off the image centre, with skew: a mirror about the image's width
# or about (cx, cy) without the skew would not pass these tests.
K = np.array([[1150.0, 3.0, 430.0], [0.0, 1120.0, 610.0], [0.0, 0.0, 1.0]], np.float32)
MIRROR_2D = np.array([-1.0, 1.0], np.float32)


def random_lifter(window: int = 1, seed: int = 0) -> Lifter3D:
    """An untrained frame (or temporal) lifter with random weights and batch statistics: no mirror symmetry."""
    config = ModelConfig(width=64, stages=1, blocks_per_stage=1, dropout_rate=0.0, temporal_window=window)
    model = config.build(H36M_17.num_joints)
    variables = model.init(jax.random.key(seed), jnp.zeros(model.input_shape(2)), train=False)
    randomized = jax.tree.map(lambda v: v + 0.3 * jax.random.normal(jax.random.key(seed + 1), v.shape), variables)
    randomized["batch_stats"] = jax.tree.map(jnp.abs, randomized["batch_stats"])  # variances stay positive
    return Lifter3D(H36M_17, config, randomized, 0, pathlib.Path("untrained"), make_eval_step(model, config))


def to_pixels(normalized: np.ndarray) -> np.ndarray:
    """Normalised camera coordinates [..., 2] -> pixels of `K`."""
    homogeneous = np.concatenate([normalized, np.ones_like(normalized[..., :1])], -1)
    return (homogeneous @ K.T)[..., :2].astype(np.float32)


def symmetric_poses(count: int, rng: np.random.Generator) -> np.ndarray:
    """2D poses [count, J, 2] in pixels whose mirror image (x -> -x in normalised coordinates, left and
    right swapped) is the pose itself: paired joints at mirrored places, the others on x = 0."""
    normalized = rng.uniform(-0.2, 0.2, (count, H36M_17.num_joints, 2)) + [0.0, 0.05]
    normalized[..., 0] = np.where(H36M_17.flip_permutation() == np.arange(H36M_17.num_joints), 0.0, normalized[..., 0])
    for left, right in H36M_17.left_right_pairs:
        normalized[:, right] = normalized[:, left] * MIRROR_2D
    return to_pixels(normalized)


def test_mirroring_twice_is_the_identity():
    rng = np.random.default_rng(0)
    poses = rng.normal(size=(5, 17, 3)).astype(np.float32)
    np.testing.assert_array_equal(mirror_pose3d(mirror_pose3d(poses, H36M_17), H36M_17), poses)
    keypoints, confidence = rng.normal(size=(5, 3, 17, 2)), rng.uniform(size=(5, 3, 17))  # windows of 3 frames
    twice = mirror_input(*mirror_input(keypoints, np.broadcast_to(K, (5, 3, 3)), confidence, H36M_17), H36M_17)
    for back, given in zip(twice, (keypoints, np.broadcast_to(K, (5, 3, 3)), confidence)):
        np.testing.assert_array_equal(back, given)


@pytest.mark.parametrize("mode", INPUT_NORMALIZATIONS)
def test_the_mirror_is_x_to_minus_x_of_normalised_coordinates(mode):
    """The mirrored camera's input is the lifter input of the mirror image in normalised camera coordinates
    (about the principal point), left and right swapped, in every input normalisation and window frame."""
    rng = np.random.default_rng(1)
    normalized = rng.uniform(-0.3, 0.3, (4, 3, 17, 2))  # 4 windows of 3 frames
    confidence = (rng.uniform(size=(4, 3, 17)) > 0.2).astype(np.float32)
    confidence[..., 0] = 1.0
    Ks = np.broadcast_to(K, (4, 1, 3, 3))
    keypoints, mirrored_K, mirrored_confidence = mirror_input(to_pixels(normalized), Ks, confidence, H36M_17)
    mirrored_pixels = to_pixels(normalized[..., H36M_17.flip_permutation(), :] * MIRROR_2D)
    expected = normalize_keypoints(mirrored_pixels, Ks, mirrored_confidence, mode)
    np.testing.assert_allclose(normalize_keypoints(keypoints, mirrored_K, mirrored_confidence, mode), expected, atol=1e-5)


def test_flip_average_of_a_mirror_symmetric_pose_is_mirror_symmetric():
    lifter = random_lifter()
    keypoints = symmetric_poses(6, np.random.default_rng(2))
    plain, flipped = lifter.predict(keypoints, K), lifter.predict(keypoints, K, flip=True)
    scale = np.abs(flipped).max()
    assert np.abs(mirror_pose3d(plain, H36M_17) - plain).max() > 0.05 * scale  # the network alone is not symmetric
    np.testing.assert_allclose(mirror_pose3d(flipped, H36M_17), flipped, atol=1e-5 * scale)


def test_an_equivariant_lifter_is_left_as_it_is():
    """For a lifter that is mirror-equivariant by construction, the flip average is the plain output: the
    flip-averaged random network, and a 'lifter' that places the normalised 2D pose at depth 0."""
    lifter = random_lifter()
    rng = np.random.default_rng(3)
    keypoints = to_pixels(rng.uniform(-0.3, 0.3, (8, 17, 2)))
    Ks, confidence = np.broadcast_to(K, (8, 3, 3)), np.ones((8, 17), np.float32)
    once = flip_averaged(lifter.eval_step, H36M_17)
    twice = flip_averaged(once, H36M_17)
    a, b = once(lifter.variables, keypoints, Ks, confidence), twice(lifter.variables, keypoints, Ks, confidence)
    np.testing.assert_allclose(b, a, atol=1e-5 * np.abs(a).max())

    def flat(variables, keypoints, K, confidence):
        xy = normalize_keypoints(keypoints, K, confidence, "intrinsics")
        return 1000.0 * jnp.concatenate([xy, jnp.zeros_like(xy[..., :1])], -1)

    np.testing.assert_allclose(flip_averaged(flat, H36M_17)(None, keypoints, Ks, confidence), flat(None, keypoints, Ks, confidence), atol=1e-3)


def test_predict_with_and_without_flip():
    lifter = random_lifter()
    rng = np.random.default_rng(4)
    keypoints = to_pixels(rng.uniform(-0.3, 0.3, (9, 17, 2)))
    confidence = np.ones((9, 17), np.float32)
    confidence[1, 5], confidence[2, 0] = 0.0, 0.0  # a missing joint, a missing root
    plain, flipped = lifter.predict(keypoints, K, confidence), lifter.predict(keypoints, K, confidence, flip=True)
    np.testing.assert_array_equal(np.isnan(flipped).all((1, 2)), confidence[:, 0] == 0)
    rows = confidence[:, 0] > 0
    assert np.abs(flipped[rows] - plain[rows]).max() > 0.05 * np.abs(plain[rows]).max()
    mirrored = lifter.eval_step(lifter.variables, *mirror_input(keypoints[rows], np.broadcast_to(K, (8, 3, 3)), confidence[rows], H36M_17))
    tolerance = 1e-6 * np.abs(plain[rows]).max()
    np.testing.assert_allclose(flipped[rows], 0.5 * (plain[rows] + mirror_pose3d(mirrored, H36M_17)), atol=tolerance)
    np.testing.assert_allclose(lifter.predict(keypoints[3], K, flip=True), flipped[3], atol=tolerance)  # one pose


def test_a_temporal_lifter_flips_every_frame_of_its_window():
    lifter = random_lifter(window=3)
    sequence = symmetric_poses(7, np.random.default_rng(5))
    flipped = lifter.predict(sequence, K, flip=True)
    scale = np.abs(flipped).max()
    assert np.abs(lifter.predict(sequence, K) - flipped).max() > 0.05 * scale
    np.testing.assert_allclose(mirror_pose3d(flipped, H36M_17), flipped, atol=1e-5 * scale)


@pytest.mark.parametrize("window", [1, 3])
def test_exported_forms_hold_the_flip(window, tmp_path):
    onnxruntime = pytest.importorskip("onnxruntime")
    lifter = random_lifter(window)
    rng = np.random.default_rng(6)
    sequence = to_pixels(rng.uniform(-0.3, 0.3, (5, 17, 2)))
    confidence = np.ones((5, 17), np.float32)
    confidence[1, 4] = 0.0
    expected = lifter.predict(sequence, K, confidence, flip=True)
    if window == 1:
        keypoints, scores = sequence, confidence
    else:  # each frame's window, the ends repeated, as predict reads a sequence
        rows = np.clip(np.arange(5)[:, None] + np.arange(3) - 1, 0, 4)
        keypoints, scores = sequence[rows], confidence[rows]
    inputs = {"keypoints": keypoints, "K": np.broadcast_to(K, (5, 3, 3)).copy(), "confidence": scores}
    path = export.export_onnx(lifter, tmp_path / "lifter.onnx", flip=True)
    (onnx_poses,) = onnxruntime.InferenceSession(str(path)).run(None, inputs)
    jax_poses = jax.export.deserialize(export.export_jax(lifter, tmp_path / "l.jax_export", flip=True).read_bytes()).call(*inputs.values())
    scale = np.abs(expected).max()
    np.testing.assert_allclose(onnx_poses, expected, atol=1e-4 * scale, rtol=0)
    np.testing.assert_allclose(np.asarray(jax_poses), expected, atol=1e-4 * scale, rtol=0)
    assert export.metadata(lifter, flip=True)["test_time_flip"] is True
    assert np.abs(expected - lifter.predict(sequence, K, confidence)).max() > 0.05 * scale


@pytest.mark.trains
def test_cli_flip_lifts_as_predict_does(trained_run, lifter, tmp_path):
    run_dir, test = trained_run
    N, C, J, _ = test.samples.keypoints2d.shape
    undistorted = test.undistorted()
    keypoints, confidence = undistorted.samples.keypoints2d.reshape(N * C, J, 2)[:40], undistorted.samples.confidence.reshape(N * C, J)[:40]
    Ks = np.asarray(test.rigs.K)[test.samples.rig_index].reshape(N * C, 3, 3)[:40]
    np.savez(tmp_path / "views.npz", keypoints=keypoints, confidence=confidence, K=Ks)
    outputs = {}
    for flag in ("--flip", "--no-flip"):
        output = tmp_path / f"poses{flag}.npz"
        predict.main(["--checkpoint", str(run_dir), "--input", str(tmp_path / "views.npz"), "--output", str(output),
                      "--min-confidence", "0", flag])  # fmt: skip
        with np.load(output) as out:
            outputs[flag] = out["pose3d_mm"]
    np.testing.assert_allclose(outputs["--flip"], lifter.predict(keypoints, Ks, confidence, flip=True), atol=1e-3)
    np.testing.assert_allclose(outputs["--no-flip"], lifter.predict(keypoints, Ks, confidence), atol=1e-3)
    lifted = np.isfinite(outputs["--flip"]).all((1, 2))
    assert np.abs(outputs["--flip"][lifted] - outputs["--no-flip"][lifted]).mean() > 0.1  # mm
