"""Geometry: projection, undistortion, projection matrices and DLT triangulation."""

import jax.numpy as jnp
import numpy as np
import pytest
from geometry_helpers import random_poses, random_rig
from hypothesis import given
from hypothesis import strategies as st

from jaxpose.camera import (
    camera_centres,
    camera_to_world,
    normalize_keypoints,
    project,
    projection_matrices,
    undistort_points,
    world_to_camera,
)
from jaxpose.triangulation import triangulate, triangulate_cameras


def test_world_camera_round_trip_and_centres():
    rng = np.random.default_rng(0)
    cameras = random_rig(rng, 4)
    points = jnp.asarray(random_poses(rng, 4, 17))
    back = camera_to_world(cameras, world_to_camera(cameras, points))
    np.testing.assert_allclose(back, points, atol=1e-2)
    # The centre maps to the camera origin.
    origin = world_to_camera(cameras, camera_centres(cameras.R, cameras.t)[:, None, :])
    np.testing.assert_allclose(origin, 0.0, atol=1e-2)


def test_project_matches_projection_matrix_oracle():
    rng = np.random.default_rng(1)
    cameras = random_rig(rng, 3)
    points = random_poses(rng, 1, 17)[0]
    P = np.asarray(projection_matrices(cameras), np.float64)
    homogeneous = np.concatenate([points, np.ones((17, 1))], 1).astype(np.float64)
    expected = np.einsum("cij,nj->cni", P, homogeneous)
    expected = expected[..., :2] / expected[..., 2:]
    np.testing.assert_allclose(project(cameras, jnp.asarray(points)[None]), expected, atol=1e-2)


@pytest.mark.parametrize("model", ["opencv", "h36m"])
def test_undistort_inverts_distortion(model):
    rng = np.random.default_rng(2)
    cameras = random_rig(rng, 4)
    dist = jnp.asarray(np.tile([-0.2, 0.1, 0.001, -0.002, 0.01], (4, 1)), jnp.float32)
    distorted_cameras = cameras.replace(dist=dist, distortion_model=model)
    points = jnp.asarray(random_poses(rng, 1, 17))
    pinhole = project(cameras, points)
    distorted = project(distorted_cameras, points)
    assert float(jnp.abs(distorted - pinhole).max()) > 1.0  # the distortion is not negligible
    np.testing.assert_allclose(undistort_points(distorted_cameras, distorted), pinhole, atol=2e-3)


def test_opencv_distortion_matches_closed_form():
    rng = np.random.default_rng(3)
    cameras = random_rig(rng, 1)
    k1, k2, p1, p2, k3 = -0.25, 0.12, 0.0015, -0.001, 0.02
    distorted_cameras = cameras.replace(dist=jnp.asarray([[k1, k2, p1, p2, k3]], jnp.float32))
    points = jnp.asarray(random_poses(rng, 1, 17))
    camera_points = np.asarray(world_to_camera(cameras, points), np.float64)[0]
    x, y = camera_points[:, 0] / camera_points[:, 2], camera_points[:, 1] / camera_points[:, 2]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = np.asarray(cameras.K[0], np.float64)
    expected = np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], -1)
    np.testing.assert_allclose(project(distorted_cameras, points)[0], expected, atol=1e-2)


@given(
    seed=st.integers(0, 2**31 - 1),
    num_views=st.sampled_from([2, 3, 4, 8]),
    method=st.sampled_from(["svd", "eigh", "normal"]),
)
def test_triangulate_recovers_points_from_exact_projections(seed, num_views, method):
    rng = np.random.default_rng(seed)
    cameras = random_rig(rng, num_views)
    points = random_poses(rng, 1, 17)[0]
    pixels = project(cameras, jnp.asarray(points)[None])
    estimate = triangulate(projection_matrices(cameras), pixels, method=method)
    tolerance = 0.1 if method != "eigh" else 0.5  # eigh squares the condition number in float32
    assert np.abs(np.asarray(estimate) - points).max() < tolerance


@given(seed=st.integers(0, 2**31 - 1), num_views=st.sampled_from([3, 4, 8]), garbage=st.sampled_from([1e4, -3e5, np.nan, np.inf]))
def test_zero_weight_view_is_ignored(seed, num_views, garbage):
    rng = np.random.default_rng(seed)
    cameras = random_rig(rng, num_views)
    points = random_poses(rng, 1, 17)[0]
    pixels = project(cameras, jnp.asarray(points)[None])
    weights = jnp.ones(pixels.shape[:-1])
    clean = triangulate(projection_matrices(cameras), pixels, weights)
    bad_view = int(rng.integers(num_views))
    corrupted = pixels.at[bad_view].set(garbage)
    weights = weights.at[bad_view].set(0.0)
    estimate = triangulate(projection_matrices(cameras), corrupted, weights)
    assert np.isfinite(np.asarray(estimate)).all()
    np.testing.assert_allclose(estimate, clean, atol=0.05)
    assert np.abs(np.asarray(estimate) - points).max() < 0.1


def test_triangulate_batched_matches_loop_and_svd_reference_under_noise():
    rng = np.random.default_rng(5)
    rigs = [random_rig(rng, 4) for _ in range(3)]
    P = jnp.stack([projection_matrices(r) for r in rigs])
    points = random_poses(rng, 3, 17)
    pixels = jnp.stack([project(r, jnp.asarray(p)[None]) for r, p in zip(rigs, points)])
    noisy = pixels + jnp.asarray(rng.normal(0, 3, pixels.shape), jnp.float32)
    batched = triangulate(P, noisy)
    looped = jnp.stack([triangulate(P[i], noisy[i]) for i in range(3)])
    np.testing.assert_allclose(batched, looped, atol=1e-3)
    # All solvers agree closely under realistic noise (few mm), and stay near the truth.
    for method in ("eigh", "normal"):
        other = triangulate(P, noisy, method=method)
        assert float(jnp.abs(other - batched).max()) < 5.0
    assert float(jnp.linalg.norm(batched - points, axis=-1).mean()) < 30.0


def test_triangulate_cameras_handles_distortion():
    rng = np.random.default_rng(6)
    cameras = random_rig(rng, 4).replace(dist=jnp.asarray(np.tile([-0.2, 0.05, 0, 0, 0], (4, 1)), jnp.float32))
    points = random_poses(rng, 1, 17)[0]
    estimate = triangulate_cameras(cameras, project(cameras, jnp.asarray(points)[None]))
    assert np.abs(np.asarray(estimate) - points).max() < 0.5


def test_triangulate_rejects_bad_shapes():
    P = jnp.zeros((4, 3, 4))
    with pytest.raises(ValueError, match="points2d"):
        triangulate(P, jnp.zeros((3, 17, 2)))
    with pytest.raises(ValueError, match="at least 2 views"):
        triangulate(P[:1], jnp.zeros((1, 17, 2)))
    with pytest.raises(ValueError, match="weights"):
        triangulate(P, jnp.zeros((4, 17, 2)), jnp.ones((4, 16)))


def test_normalize_keypoints_is_camera_and_distance_invariant():
    rng = np.random.default_rng(7)
    cameras = random_rig(rng, 4)
    pose = jnp.asarray(random_poses(rng, 1, 17))
    # The RMS scale here (the median scale's own test is in test_robust_input.py).
    near = normalize_keypoints(project(cameras, pose), cameras.K, mode="intrinsics_scale")
    # A different focal length/principal point gives the same normalized input.
    K2 = cameras.K.at[:, 0, 0].multiply(1.5).at[:, 1, 1].multiply(1.5).at[:, 0, 2].add(40.0)
    cameras2 = cameras.replace(K=K2)
    np.testing.assert_allclose(normalize_keypoints(project(cameras2, pose), K2, mode="intrinsics_scale"), near, atol=1e-4)
    assert np.allclose(near[:, 0], 0.0)
    rms = np.sqrt((np.asarray(near) ** 2).sum(-1).sum(-1) / 16)
    np.testing.assert_allclose(rms, 1.0, rtol=1e-4)
    # Missing joints are zeroed, never NaN, and a missing root zeroes the whole pose.
    confidence = jnp.ones((4, 17)).at[1, 5].set(0.0).at[2, 0].set(0.0)
    masked = np.asarray(normalize_keypoints(project(cameras, pose), cameras.K, confidence))
    assert np.isfinite(masked).all() and np.all(masked[1, 5] == 0) and np.all(masked[2] == 0)
