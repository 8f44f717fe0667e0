"""jaxpose.rotations: Rodrigues vectors against scipy, and the nearest rotation."""

from __future__ import annotations

import hypothesis.strategies as st
import numpy as np
from hypothesis import given, settings
from scipy.spatial.transform import Rotation

from jaxpose.rotations import nearest_rotation, rodrigues_from_rotation, rotation_from_rodrigues


@settings(max_examples=200)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), st.floats(0.0, np.pi))
def test_rodrigues_against_scipy(direction, angle):
    direction = np.asarray(direction)
    norm = np.linalg.norm(direction)
    vector = np.zeros(3) if norm < 1e-6 else direction / norm * angle
    matrix = rotation_from_rodrigues(vector)
    np.testing.assert_allclose(matrix, Rotation.from_rotvec(vector).as_matrix(), atol=1e-13)
    back = rodrigues_from_rotation(matrix)
    np.testing.assert_allclose(rotation_from_rodrigues(back), matrix, atol=1e-13)
    if np.linalg.norm(vector) < np.pi - 1e-6:  # at pi, +axis and -axis are the same rotation
        np.testing.assert_allclose(back, vector, atol=1e-9)
        np.testing.assert_allclose(back, Rotation.from_matrix(matrix).as_rotvec(), atol=1e-9)


def test_rodrigues_batches_and_half_turns():
    vectors = np.array([[np.pi, 0, 0], [0, 0, -np.pi], np.array([1, 1, 1]) / np.sqrt(3) * np.pi, [0, 0, 0], [1e-9, 0, 0]])
    matrices = rotation_from_rodrigues(vectors)
    np.testing.assert_allclose(matrices, Rotation.from_rotvec(vectors).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(rotation_from_rodrigues(rodrigues_from_rotation(matrices)), matrices, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(rodrigues_from_rotation(matrices)[:3], axis=-1), np.pi, atol=1e-12)


def test_nearest_rotation_keeps_rotations_and_never_reflects():
    rotations = Rotation.random(5, random_state=0).as_matrix()
    np.testing.assert_allclose(nearest_rotation(rotations), rotations, atol=1e-14)
    rng = np.random.default_rng(0)
    rounded = np.round(rotations, 4)  # as a file written with four digits holds them
    nearest = nearest_rotation(rounded)
    np.testing.assert_allclose(nearest @ np.swapaxes(nearest, -1, -2), np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-14)
    np.testing.assert_allclose(nearest, rotations, atol=1e-4)
    reflection = rotations[0] @ np.diag([1.0, 1.0, -1.0]) + rng.normal(0.0, 1e-3, (3, 3))
    assert np.linalg.det(nearest_rotation(reflection)) > 0.0
    assert nearest_rotation(rotations.astype(np.float32)).dtype == np.float64
