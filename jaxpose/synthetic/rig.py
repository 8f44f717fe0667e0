"""The simulated camera room: a Human3.6M-like rig around the capture area, its per-subject
calibration jitter, and the projection of world points into it."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import Cameras, camera_centres, project_from_camera, world_to_camera
from jaxpose.synthetic.body import axis_rotation
from jaxpose.synthetic.config import SyntheticConfig


def _look_at(centers: np.ndarray, targets: np.ndarray, roll_degrees: np.ndarray) -> np.ndarray:
    """World-to-camera rotations [C, 3, 3] of cameras at `centers` looking at `targets` (world z up).

    Rows are the camera axes in world coordinates: x right, y down in the image, z forward.
    """
    forward = targets - centers
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward], axis=-2)
    return axis_rotation(2, roll_degrees) @ rotation  # roll about the optical axis


def _cameras(K: np.ndarray, R: np.ndarray, centers: np.ndarray) -> Cameras:
    """Float32 numpy `Cameras` from intrinsics, rotations and camera centres (t = -R c)."""
    t = -np.einsum("cij,cj->ci", R, centers)
    return Cameras(K=K.astype(np.float32), R=R.astype(np.float32), t=t.astype(np.float32), dist=None)


def make_rig(rng: np.random.Generator, config: SyntheticConfig) -> Cameras:
    """A Human3.6M-like room: `num_views` cameras [C] around the capture area, looking at its centre.

    Cameras sit on a circle (radius in `camera_distance`, evenly spaced azimuths +-10 degrees) at
    heights in `camera_height`, aimed at about 1 m above the room centre; focal lengths vary a few
    percent, principal points lie near the image centre.  Pinhole (dist None), float32 numpy fields.
    """
    C = config.num_views
    azimuth = rng.uniform(0.0, 2.0 * np.pi) + 2.0 * np.pi * np.arange(C) / C + np.radians(rng.uniform(-10, 10, C))
    radius = rng.uniform(*config.camera_distance, C)
    centers = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), rng.uniform(*config.camera_height, C)], 1)
    targets = np.stack([rng.normal(0.0, 150.0, C), rng.normal(0.0, 150.0, C), rng.normal(1000.0, 100.0, C)], 1)
    R = _look_at(centers, targets, rng.normal(0.0, 1.0, C))
    focal = config.focal_length * np.clip(1.0 + rng.normal(0.0, 0.02, C), 0.95, 1.05)
    K = np.zeros((C, 3, 3))
    K[:, 0, 0] = focal
    K[:, 1, 1] = focal * (1.0 + rng.normal(0.0, 0.002, C))  # nearly square pixels
    K[:, :2, 2] = np.asarray(config.image_size, np.float64) / 2.0 + rng.normal(0.0, 8.0, (C, 2))
    K[:, 2, 2] = 1.0
    return _cameras(K, R, centers)


def jitter_rig(rng: np.random.Generator, rig: Cameras) -> Cameras:
    """One subject's calibration of the room: the cameras moved ~2 cm, turned ~0.5 degrees,
    refocused ~0.5%, as repeated calibrations of one studio differ."""
    R, t, K = (np.asarray(field, np.float64) for field in (rig.R, rig.t, rig.K))
    C = len(K)
    centers = camera_centres(R, t) + rng.normal(0.0, 20.0, (C, 3))
    tilt = axis_rotation(0, rng.normal(0.0, 0.5, C)) @ axis_rotation(1, rng.normal(0.0, 0.5, C))
    R = tilt @ axis_rotation(2, rng.normal(0.0, 0.5, C)) @ R
    K = K.copy()
    K[:, [0, 1], [0, 1]] *= 1.0 + rng.normal(0.0, 0.005, (C, 1))
    K[:, :2, 2] += rng.normal(0.0, 2.0, (C, 2))
    return _cameras(K, R, centers)


def project_points(rig: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`jaxpose.camera.project` of world points [N, J, 3] into a numpy rig [C]: (pixels f64[N, C, J, 2],
    depth f64[N, C, J] in mm).  In float64 on the rig's stored (float32) values, so that the stored
    rig reproduces the clean projections to float32 precision."""
    with jax.enable_x64(True):
        cameras = Cameras(**{name: jnp.asarray(getattr(rig, name), jnp.float64) for name in ("K", "R", "t")}, dist=None)
        points_camera = world_to_camera(cameras, jnp.asarray(points, jnp.float64)[:, None])  # [N, C, J, 3]
        pixels = project_from_camera(cameras, points_camera)
        return np.asarray(pixels), np.asarray(points_camera[..., 2])
