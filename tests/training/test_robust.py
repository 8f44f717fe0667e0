"""Robust pseudo-labels: outlier and swap rejection, validity weights, NaN-proof masking, dispatch."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from geometry_helpers import LOSS_TERMS, exact_batch, look_at, random_poses

from jaxpose import robust
from jaxpose.training import pseudo_labelling
from jaxpose.training.config import PseudoLabelConfig
from jaxpose.camera import Cameras, normalize_keypoints, project, projection_matrices
from jaxpose.data.batch import MultiViewBatch, validate_batch
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.data.samples import Samples
from jaxpose import losses
from jaxpose.losses import LossWeights, total_loss
from jaxpose.skeleton import H36M_17

METHODS = robust.PSEUDO_LABEL_METHODS
ROBUST = ("irls", "ransac")
B, C, J = 6, 4, 17


def ring_batch(rng: np.random.Generator, batch: int, views: int, joints: int) -> MultiViewBatch:
    """Exact projections of random point sets into `views` cameras evenly spaced on a 5 m ring (a
    studio-like rig: IRLS starts from the DLT, which needs views spread around the subject)."""
    cameras = []
    for _ in range(batch):
        azimuths = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(views) / views
        centres = [np.array([5000 * np.cos(a), 5000 * np.sin(a), rng.uniform(1000, 2500)]) for a in azimuths]
        R, t = zip(*(look_at(c, np.array([0.0, 0.0, 1000.0])) for c in centres))
        K = np.tile(np.array([[1150.0, 0, 500], [0, 1150, 500], [0, 0, 1]]), (views, 1, 1))
        cameras.append(Cameras(K=K, R=np.stack(R), t=np.stack(t)))
    cameras = jax.tree.map(lambda *fields: jnp.asarray(np.stack(fields), jnp.float32), *cameras)
    poses = jnp.asarray(random_poses(rng, batch, joints))
    keypoints = project(cameras, poses[:, None])
    confidence = jnp.ones(keypoints.shape[:-1], jnp.float32)
    return MultiViewBatch(keypoints2d=keypoints, confidence=confidence, cameras=cameras, pseudo3d=poses, target3d=poses)


@pytest.fixture(scope="module")
def scene():
    """A ring rig of 4 views, exact projections, confidence 1."""
    batch = ring_batch(np.random.default_rng(0), B, C, J)
    return batch, projection_matrices(batch.cameras)


_solve = jax.jit(robust.pseudo_labels, static_argnames=("method",))


def _error(points, truth):
    return np.linalg.norm(np.asarray(points) - np.asarray(truth), axis=-1)


@pytest.mark.parametrize("method", METHODS)
def test_exact_projections_give_the_truth_with_weight_one(scene, method):
    batch, P = scene
    points, weight = _solve(P, batch.keypoints2d, batch.confidence, method=method)
    assert points.shape == (B, J, 3) and weight.shape == (B, J)
    assert _error(points, batch.target3d).max() < 1.0
    np.testing.assert_array_equal(weight, 1.0)


def test_reprojection_residuals_match_project_and_flag_points_behind():
    batch, _ = exact_batch(np.random.default_rng(1), 2, 3, 5)
    P = projection_matrices(batch.cameras)
    shifted = batch.keypoints2d + jnp.array([3.0, 4.0])
    residuals = jax.jit(robust.reprojection_residuals)
    np.testing.assert_allclose(residuals(P, shifted, batch.target3d), 5.0, atol=1e-2)
    # The camera centre of view 0 moved 1 m backwards along its optical axis: behind view 0 only.
    R, t = batch.cameras.R[0, 0], batch.cameras.t[0, 0]
    behind = (-R.T @ t - 1000.0 * R[2])[None, None]
    residual = residuals(P[:1], batch.keypoints2d[:1, :, :1], behind)
    assert residual[0, 0, 0] == robust.BEHIND_CAMERA_PX and residual[0, 1, 0] < robust.BEHIND_CAMERA_PX


def test_one_gross_outlier_moves_the_dlt_but_not_the_robust_methods(scene):
    batch, P = scene
    keypoints = batch.keypoints2d.at[:, 1, 5].add(jnp.array([80.0, -60.0]))  # confidence stays 1
    for method in ("svd", "unweighted"):
        points, _ = _solve(P, keypoints, batch.confidence, method=method)
        assert _error(points, batch.target3d)[:, 5].min() > 5.0
    for method in ROBUST:
        points, weight = _solve(P, keypoints, batch.confidence, method=method)
        assert _error(points, batch.target3d).max() < 1.0, method
        np.testing.assert_array_equal(weight, 1.0)


def test_ransac_rejects_a_left_right_swap_in_one_view(scene):
    """The swapped joints of these random point sets land up to ~250 px away: too far for IRLS,
    whose start the swap drags by up to a metre (see the module docstring of jaxpose.robust)."""
    batch, P = scene
    flip = np.asarray(H36M_17.flip_permutation())
    keypoints = batch.keypoints2d.at[:, 2].set(batch.keypoints2d[:, 2, flip])
    points, weight = _solve(P, keypoints, batch.confidence, method="ransac")
    # A swap that moves a joint by less than about the threshold cannot be told from noise.
    moved = np.asarray(jnp.linalg.norm(keypoints[:, 2] - batch.keypoints2d[:, 2], axis=-1))
    far = moved > 2 * robust.DEFAULT_THRESHOLD_PX
    assert far.sum() > B * 4
    assert _error(points, batch.target3d)[far].max() < 1.0
    np.testing.assert_array_equal(weight, 1.0)


def test_ransac_needs_only_two_consistent_views():
    batch, _ = exact_batch(np.random.default_rng(4), B, C, J)  # random rigs, some with narrow baselines
    P = projection_matrices(batch.cameras)
    keypoints = batch.keypoints2d.at[:, 0, 3].add(jnp.array([90.0, 40.0])).at[:, 3, 3].add(jnp.array([-50.0, 120.0]))
    points, weight = _solve(P, keypoints, batch.confidence, method="ransac")
    assert _error(points, batch.target3d).max() < 1.0
    np.testing.assert_array_equal(weight, 1.0)


@functools.partial(jax.jit, static_argnames=("joint",))
def _off_epipolar(batch, joint: int, pixels: float) -> jax.Array:
    """View 1's detection of `joint` moved `pixels` across its epipolar line (the image of view 0's ray)."""
    centre = -batch.cameras.R[:, 0].transpose(0, 2, 1) @ batch.cameras.t[:, 0, :, None]  # [B, 3, 1]
    far = batch.target3d[:, joint] + (batch.target3d[:, joint] - centre[..., 0])  # twice as far on the ray
    near_far = jnp.stack([batch.target3d[:, joint], far], axis=1)  # [B, 2, 3]
    line = project(batch.cameras[:, 1], near_far)  # [B, 2, 2]
    direction = line[:, 1] - line[:, 0]
    normal = jnp.stack([-direction[:, 1], direction[:, 0]], -1) / jnp.linalg.norm(direction, axis=-1, keepdims=True)
    return batch.keypoints2d.at[:, 1, joint].add(pixels * normal)


def test_a_joint_without_agreeing_views_gets_weight_zero():
    batch, _ = exact_batch(np.random.default_rng(2), 3, 2, J)
    P = projection_matrices(batch.cameras)
    keypoints = _off_epipolar(batch, joint=7, pixels=120.0)
    for method in ROBUST:
        _, weight = _solve(P, keypoints, batch.confidence, method=method)
        np.testing.assert_array_equal(weight[:, 7], 0.0)
        np.testing.assert_array_equal(np.delete(np.asarray(weight), 7, axis=1), 1.0)
    _, weight = _solve(P, keypoints, batch.confidence, method="svd")  # the plain DLT cannot tell
    np.testing.assert_array_equal(weight, 1.0)


@pytest.mark.parametrize("method", METHODS)
def test_a_joint_seen_by_one_view_gets_weight_zero(scene, method):
    batch, P = scene
    confidence = batch.confidence.at[:, 1:, 9].set(0.0)
    _, weight = _solve(P, batch.keypoints2d, confidence, method=method)
    np.testing.assert_array_equal(weight[:, 9], 0.0)
    assert float(weight.sum()) == B * (J - 1)


@pytest.mark.parametrize("garbage", [np.nan, np.inf, -1e30])
@pytest.mark.parametrize("method", METHODS)
def test_confidence_zero_detections_contribute_nothing(scene, method, garbage):
    batch, P = scene
    confidence = batch.confidence.at[:, 2].set(0.0).at[:, 0, 4].set(0.0).at[0, 1:, 11].set(0.0)
    missing = confidence == 0
    clean = jnp.where(missing[..., None], 0.0, batch.keypoints2d)
    dirty = jnp.where(missing[..., None], garbage, batch.keypoints2d)
    expected = _solve(P, clean, confidence, method=method)
    points, weight = _solve(P, dirty, confidence, method=method)
    assert np.isfinite(points).all() and np.isfinite(weight).all()
    np.testing.assert_array_equal(points, expected[0])
    np.testing.assert_array_equal(weight, expected[1])
    assert weight[0, 11] == 0.0 and _error(points, batch.target3d)[weight > 0].max() < 1.0
    # The lifter input ignores them too.
    lifter_input = jax.jit(normalize_keypoints)
    expected_input = lifter_input(clean, batch.cameras.K, confidence)
    np.testing.assert_array_equal(lifter_input(dirty, batch.cameras.K, confidence), expected_input)


def test_batched_over_any_leading_axes(scene):
    batch, P = scene
    keypoints = batch.keypoints2d.at[:, 1, 5].add(70.0)
    for method in ROBUST:
        flat = _solve(P, keypoints, batch.confidence, method=method)
        nested = _solve(
            P.reshape(2, 3, C, 3, 4),
            keypoints.reshape(2, 3, C, J, 2),
            batch.confidence.reshape(2, 3, C, J),
            method=method,
        )
        np.testing.assert_allclose(nested[0].reshape(B, J, 3), flat[0], atol=1e-3)
        np.testing.assert_array_equal(nested[1].reshape(B, J), flat[1])


def test_unknown_method_is_named():
    with pytest.raises(ValueError, match="unknown pseudo-label method 'lmeds'"):
        robust.pseudo_labels(jnp.zeros((2, 3, 4)), jnp.zeros((2, 1, 2)), jnp.ones((2, 1)), "lmeds")


def _dataset(batch) -> MultiViewDataset:
    """One rig per sample, so that the data set reproduces the batch exactly."""
    samples = Samples(
        keypoints2d=np.asarray(batch.keypoints2d),
        confidence=np.asarray(batch.confidence),
        rig_index=np.arange(len(batch.keypoints2d), dtype=np.int32),
        target3d=np.asarray(batch.target3d),
    )
    return MultiViewDataset(skeleton=H36M_17, rigs=jax.tree.map(np.asarray, batch.cameras), samples=samples)


def test_labelling_dispatches_and_a_bad_root_voids_its_sample(scene):
    batch, P = scene
    keypoints = _off_epipolar(batch, joint=0, pixels=200.0)  # view 1's root: off by 200 px ...
    keypoints = keypoints.at[:, 2:, 0].set(0.0)  # ... and only views 0 and 1 see the root
    confidence = batch.confidence.at[:, 2:, 0].set(0.0)
    data = _dataset(batch.replace(keypoints2d=keypoints, confidence=confidence))
    plain = pseudo_labelling.label(data, PseudoLabelConfig("svd"), chunk_size=4)  # chunks of 4 rows, the last one padded
    np.testing.assert_array_equal(plain.samples.pseudo3d_weight, 1.0)
    for method in ROBUST:
        labelled = pseudo_labelling.label(data, PseudoLabelConfig(method, threshold_px=25.0), chunk_size=4)
        np.testing.assert_array_equal(labelled.samples.pseudo3d_weight, 0.0)  # root rejected -> whole sample
        validate_batch(labelled.batch(np.arange(B)))  # rejected labels need not lie in front of cameras
    good = pseudo_labelling.label(_dataset(batch), PseudoLabelConfig("ransac"), chunk_size=4)
    np.testing.assert_array_equal(good.samples.pseudo3d_weight, 1.0)
    assert _error(good.samples.pseudo3d, batch.target3d).max() < 1.0


def test_zero_weight_labels_teach_nothing_through_any_loss(scene):
    """With weight 0 a pseudo-label's value cannot change the loss or its gradient (all four terms)."""
    batch, _ = scene
    in_camera = jnp.einsum("bcij,bnj->bcni", batch.cameras.R, batch.target3d)  # root-relative: no t needed
    truth = in_camera - in_camera[:, :, :1]
    pred = truth + jnp.asarray(np.random.default_rng(3).normal(0.0, 30.0, truth.shape), jnp.float32)
    weight = jnp.ones((B, J)).at[:, 6].set(0.0).at[2].set(0.0)  # joint 6 everywhere; all of sample 2 (its root)
    garbage = batch.pseudo3d.at[:, 6].add(5e4).at[2].add(jnp.array([3e4, -2e4, 1e4]))
    weights = LossWeights(output_triangulation=0.01)

    @jax.jit
    def loss_and_grad(pseudo3d):
        labelled = batch.replace(pseudo3d=pseudo3d, pseudo3d_weight=weight)
        return jax.value_and_grad(lambda p: total_loss(p, labelled, weights), has_aux=True)(pred)

    (loss, terms), grad = loss_and_grad(batch.pseudo3d)
    (loss_g, terms_g), grad_g = loss_and_grad(garbage)
    for name in terms:
        np.testing.assert_allclose(terms_g[name], terms[name], rtol=1e-6, err_msg=name)
    np.testing.assert_allclose(grad_g, grad, rtol=1e-5, atol=1e-9)
    assert np.isfinite(grad).all() and float(loss) > 0


def test_robust_labels_mark_the_outlying_detections_and_the_batch_carries_them(scene):
    batch, _ = scene
    keypoints = batch.keypoints2d.at[:, 1, 5].add(jnp.array([80.0, -60.0]))  # one gross outlier per sample
    data = _dataset(batch.replace(keypoints2d=keypoints))
    assert pseudo_labelling.label(data).samples.detection_weight is None  # the plain DLT rejects nothing
    for method in ROBUST:
        labelled = pseudo_labelling.label(data, PseudoLabelConfig(method, threshold_px=25.0))
        expected = np.ones((B, C, J), np.float32)
        expected[:, 1, 5] = 0.0
        np.testing.assert_array_equal(labelled.samples.detection_weight, expected, err_msg=method)
        np.testing.assert_array_equal(labelled.subset(np.array([2, 0])).samples.detection_weight, expected[[2, 0]])
        labelled_batch = labelled.batch(np.arange(B))
        np.testing.assert_array_equal(labelled_batch.detection_weight, expected)
        validate_batch(labelled_batch)


def test_an_outlier_detection_is_no_target_of_any_loss(scene):
    """A detection with detection_weight 0 may hold anything: no loss term and no gradient changes
    (the lifter output is given here; in training the detection is still an input)."""
    batch, _ = scene
    in_camera = jnp.einsum("bcij,bnj->bcni", batch.cameras.R, batch.target3d)
    truth = in_camera - in_camera[:, :, :1]
    pred = truth + jnp.asarray(np.random.default_rng(5).normal(0.0, 30.0, truth.shape), jnp.float32)
    detection_weight = jnp.ones((B, C, J)).at[:, 1, 5].set(0.0).at[:, 3, 9].set(0.0)
    weights = LossWeights(output_triangulation=0.01)

    @jax.jit
    def loss_and_grad(keypoints, pred):
        marked = batch.replace(keypoints2d=keypoints, detection_weight=detection_weight)
        return jax.value_and_grad(lambda p: total_loss(p, marked, weights), has_aux=True)(pred)

    # View 3's prediction of joint 9 is far off too, so it would drag L_out's target if it voted.
    outlying_pred = pred.at[:, 3, 9].add(jnp.array([400.0, -300.0, 200.0]))
    garbage = batch.keypoints2d.at[:, 1, 5].add(jnp.array([3e3, -2e3])).at[:, 3, 9].set(-1e4)
    for predicted in (pred, outlying_pred):
        (_, terms), grad = loss_and_grad(batch.keypoints2d, predicted)
        (_, terms_g), grad_g = loss_and_grad(garbage, predicted)
        for name in terms:
            np.testing.assert_allclose(terms_g[name], terms[name], rtol=1e-6, err_msg=name)
        np.testing.assert_allclose(grad_g, grad, rtol=1e-5, atol=1e-9)
    marked = batch.replace(detection_weight=detection_weight)
    target = jax.jit(losses.output_triangulation)(truth.at[:, 3, 9].add(jnp.array([400.0, -300.0, 200.0])), marked)
    assert _error(target, batch.target3d)[:, 9].max() < 1.0  # the outlying view had no vote on joint 9
    unmarked = jax.jit(losses.output_triangulation)(truth.at[:, 3, 9].add(jnp.array([400.0, -300.0, 200.0])), batch)
    assert _error(unmarked, batch.target3d)[:, 9].min() > 10.0


def test_an_untrusted_joint_gets_no_gradient_from_any_loss(scene):
    batch, _ = scene
    in_camera = jnp.einsum("bcij,bnj->bcni", batch.cameras.R, batch.target3d)
    pred = in_camera - in_camera[:, :, :1] + jnp.asarray(np.random.default_rng(6).normal(0.0, 30.0, in_camera.shape))
    pred = pred.at[:, :, 0].set(0.0)
    untrusted = batch.replace(pseudo3d_weight=jnp.ones((B, J)).at[:, 6].set(0.0))
    for name, term in LOSS_TERMS.items():
        gradient = np.asarray(jax.jit(jax.grad(term))(pred, untrusted))
        assert np.abs(gradient[..., 6, :]).max() == 0.0, name
        assert np.abs(gradient[..., 7, :]).max() > 0.0, name


def test_labelling_passes_every_config_field_to_the_solver(scene):
    batch, P = scene
    keypoints = batch.keypoints2d.at[:, 1, 5].add(jnp.array([12.0, -9.0]))  # 15 px off: beyond 10, within 25
    data = _dataset(batch.replace(keypoints2d=keypoints))
    config = PseudoLabelConfig(method="irls", min_views=3, threshold_px=10.0, irls_iterations=2, irls_scale_px=8.0)
    labelled = pseudo_labelling.label(data, config)
    points, weight = robust.pseudo_labels(
        P, keypoints, batch.confidence, "irls", min_views=3, threshold_px=10.0, irls_iterations=2, irls_scale_px=8.0
    )
    np.testing.assert_allclose(labelled.samples.pseudo3d, points, rtol=1e-6, atol=1e-3)
    np.testing.assert_array_equal(labelled.samples.pseudo3d_weight, weight * weight[:, :1])
    np.testing.assert_array_equal(labelled.samples.detection_weight[:, 1, 5], 0.0)  # rejected at 10 px ...
    default = pseudo_labelling.label(data, PseudoLabelConfig(method="irls"))
    np.testing.assert_array_equal(default.samples.detection_weight[:, 1, 5], 1.0)  # ... kept at the default 25 px


@pytest.mark.trains
def test_the_comparison_command_writes_its_table(tmp_path):
    from experiments import pseudo_labels

    argv = ["--samples-per-subject", "40", "--scenarios", "harsh-noconf", "--methods", "svd", "ransac"]
    table = pseudo_labels.main([*argv, "--run-dir", str(tmp_path)])
    assert (tmp_path / "table.md").read_text().strip() == table.strip()
    assert "| harsh-noconf | `ransac` |" in table and "Lifter" not in table


@pytest.mark.trains
def test_the_comparison_command_names_a_training_it_cannot_run(tmp_path):
    from experiments import pseudo_labels

    argv = ["--train", "--scenarios", "harsh", "--methods", "svd", "--train-runs", "harsh:ransac"]
    with pytest.raises(SystemExit, match="harsh:ransac"):
        pseudo_labels.main([*argv, "--run-dir", str(tmp_path)])
