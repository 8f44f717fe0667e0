"""Simulated sessions: a rig whose cameras were moved between recordings, and recordings through a rig.

For `jaxpose.calibration.sessions`' tests and study: `moved_rig` bumps every camera of a rig (a
lab's cameras remounted between days), `record` films poses through a rig with the simulated detector.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from jaxpose.camera import Cameras, camera_centres
from jaxpose.synthetic.config import SyntheticConfig
from jaxpose.synthetic.detector import simulate_detector
from jaxpose.synthetic.rig import project_points


def _random_directions(rng: np.random.Generator, count: int) -> np.ndarray:
    directions = rng.normal(size=(count, 3))
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def moved_rig(
    rng: np.random.Generator, rig: Cameras, shift_mm: tuple[float, float] = (100.0, 500.0), turn_deg: tuple[float, float] = (1.0, 3.0)
) -> Cameras:
    """`rig` with every camera moved by U(shift_mm) mm in a random direction and turned by U(turn_deg)
    degrees about a random axis (its intrinsics kept); float32 numpy fields as `make_rig`'s."""
    R, t, K = (np.asarray(field, np.float64) for field in (rig.R, rig.t, rig.K))
    C = len(K)
    centres = camera_centres(R, t) + rng.uniform(*shift_mm, (C, 1)) * _random_directions(rng, C)
    turn = Rotation.from_rotvec(np.radians(rng.uniform(*turn_deg, (C, 1))) * _random_directions(rng, C)).as_matrix()
    R = turn @ R
    t = -np.einsum("cij,cj->ci", R, centres)
    return Cameras(K=K.astype(np.float32), R=R.astype(np.float32), t=t.astype(np.float32), dist=None)


def record(rng: np.random.Generator, rig: Cameras, poses: np.ndarray, config: SyntheticConfig) -> tuple[np.ndarray, np.ndarray]:
    """H36M_17 poses f[N, 17, 3] (world mm) filmed through `rig` by the simulated detector (`config`'s
    noise, outliers, swaps, missing joints): (keypoints f32[N, C, 17, 2], confidence f32[N, C, 17])."""
    clean, _ = project_points(rig, poses)
    detections = simulate_detector(rng, clean, config)
    return detections.keypoints2d, detections.confidence
