"""Small exact multi-view scenes for the core tests (independent of the synthetic generator)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxpose import losses
from jaxpose.camera import Cameras, project, world_to_camera
from jaxpose.data.batch import MultiViewBatch

LOSS_TERMS = {
    "input_triangulation": losses.input_triangulation_loss,
    "reprojection": losses.reprojection_loss,
    "consistency": losses.consistency_loss,
    "output_triangulation": losses.output_triangulation_loss,
}


def look_at(center: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at `center` looking at `target`, z up, image y down."""
    forward = target - center
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    return R, -R @ center


def random_rig(rng: np.random.Generator, num_views: int, distance=(3000.0, 7000.0)) -> Cameras:
    """`num_views` cameras 3-7 m from the origin at 1-2.5 m height, looking near (0, 0, 1 m)."""
    Ks, Rs, ts = [], [], []
    azimuths = np.sort(rng.uniform(0, 2 * np.pi, num_views)) + rng.uniform(0, 0.3, num_views)
    for azimuth in azimuths:
        radius = rng.uniform(*distance)
        center = np.array([radius * np.cos(azimuth), radius * np.sin(azimuth), rng.uniform(1000, 2500)])
        R, t = look_at(center, np.array([0.0, 0.0, 1000.0]) + rng.normal(0, 200, 3))
        focal = rng.uniform(900, 1400)
        Ks.append(np.array([[focal, 0, 500 + rng.normal(0, 10)], [0, focal * rng.uniform(0.98, 1.02), 500], [0, 0, 1]]))
        Rs.append(R)
        ts.append(t)
    stack = lambda xs: jnp.asarray(np.stack(xs), jnp.float32)  # noqa: E731
    return Cameras(K=stack(Ks), R=stack(Rs), t=stack(ts))


def random_poses(rng: np.random.Generator, batch: int, num_joints: int) -> np.ndarray:
    """Roughly human-sized random point sets [B, J, 3] (mm) around (0, 0, 1 m)."""
    centre = np.array([0.0, 0.0, 1000.0]) + rng.normal(0, 300, (batch, 1, 3))
    return (centre + rng.normal(0, 300, (batch, num_joints, 3))).astype(np.float32)


def exact_batch(rng: np.random.Generator, batch: int, num_views: int, num_joints: int) -> tuple[MultiViewBatch, jnp.ndarray]:
    """A batch whose 2D are exact projections and whose pseudo-label is the truth, plus the true
    root-relative pose of every view [B, C, J, 3]."""
    rigs = [random_rig(rng, num_views) for _ in range(batch)]
    cameras = Cameras(*(jnp.stack([getattr(r, f) for r in rigs]) for f in ("K", "R", "t")))
    poses = jnp.asarray(random_poses(rng, batch, num_joints))
    keypoints = project(cameras, poses[:, None])
    in_camera = world_to_camera(cameras, poses[:, None])
    truth = in_camera - in_camera[..., :1, :]
    return (
        MultiViewBatch(
            keypoints2d=keypoints,
            confidence=jnp.ones(keypoints.shape[:-1], jnp.float32),
            cameras=cameras,
            pseudo3d=poses,
            target3d=poses,
        ),
        truth,
    )
