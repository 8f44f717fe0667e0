"""Wide-angle lenses for the simulated room, and the detector seeing the person through them.

`make_rig` gives pinhole cameras; real wide-angle cameras (action cameras, a lab's 2.8 mm CCTV
lenses) add strong barrel distortion and a principal point tens of pixels off the image centre.
`wide_angle_lenses` draws such lenses (OpenCV's model: k1 barrel, k2 positive, p = k3 = 0) with the
distortion monotonic inside the image, as a real lens' is (a barrel model past its turning point
would fold the image back onto itself); `detect_through_lenses` projects world joints through them
and runs the simulated detector, dropping joints outside the image or outside the lens' field.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import Cameras, project_from_camera, world_to_camera
from jaxpose.synthetic.config import SyntheticConfig
from jaxpose.synthetic.detector import SimulatedDetections, simulate_detector

# The radial map r -> r (1 + k1 r^2 + k2 r^4) must keep at least this slope out to the image's
# farthest corner (a slope near 0 is a lens whose edge pixels each see a wide angle).
MIN_RADIAL_SLOPE = 0.2


@dataclasses.dataclass(frozen=True)
class WideAngleLenses:
    """What `wide_angle_lenses` draws from (pixels, OpenCV coefficients)."""

    focal_range: tuple[float, float] = (700.0, 1200.0)
    k1_range: tuple[float, float] = (-0.35, 0.0)
    k2_range: tuple[float, float] = (0.0, 0.1)
    max_principal_offset: float = 40.0
    """The principal point lies within this distance of the image centre (uniform in the disc)."""


def corner_radius(K: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """f64[C] the farthest image corner's distorted normalized radius (from the principal point)."""
    width, height = image_size
    corners = np.array([[0.0, 0.0], [width, 0.0], [0.0, height], [width, height]])
    offsets = (corners[None] - K[:, None, :2, 2]) / K[:, None, [0, 1], [0, 1]]
    return np.linalg.norm(offsets, axis=-1).max(-1)


def monotonic_radius(dist: np.ndarray, limit: float = 4.0, samples: int = 4000) -> np.ndarray:
    """f64[C]: the undistorted radius up to which the radial map keeps a slope >= `MIN_RADIAL_SLOPE`,
    and the distorted radius it reaches there, as (r, r_d) stacked on the last axis [C, 2]."""
    r = np.linspace(0.0, limit, samples)
    k1, k2 = dist[:, 0, None], dist[:, 1, None]
    slope = 1.0 + 3.0 * k1 * r**2 + 5.0 * k2 * r**4
    steep = slope >= MIN_RADIAL_SLOPE
    last = np.where(steep.all(-1), samples - 1, np.argmin(steep, axis=-1) - 1)
    r_end = r[last]
    return np.stack([r_end, r_end * (1.0 + k1[:, 0] * r_end**2 + k2[:, 0] * r_end**4)], axis=-1)


def wide_angle_lenses(
    rng: np.random.Generator, num_views: int, image_size: tuple[int, int], lenses: WideAngleLenses = WideAngleLenses()
) -> tuple[np.ndarray, np.ndarray]:
    """(K f64[C, 3, 3], dist f64[C, 5]) drawn uniformly from `lenses`, each redrawn until its radial
    map is monotonic (slope >= `MIN_RADIAL_SLOPE`) out to the image's farthest corner."""
    K = np.tile(np.eye(3), (num_views, 1, 1))
    dist = np.zeros((num_views, 5))
    for c in range(num_views):
        for _ in range(1000):
            focal = rng.uniform(*lenses.focal_range)
            angle, radius = rng.uniform(0.0, 2.0 * np.pi), lenses.max_principal_offset * np.sqrt(rng.uniform())
            K[c, 0, 0] = K[c, 1, 1] = focal
            K[c, :2, 2] = np.asarray(image_size, np.float64) / 2.0 + radius * np.array([np.cos(angle), np.sin(angle)])
            dist[c, :2] = rng.uniform(*lenses.k1_range), rng.uniform(*lenses.k2_range)
            if monotonic_radius(dist[c : c + 1])[0, 1] > corner_radius(K[c : c + 1], image_size)[0]:
                break
        else:
            raise ValueError(f"no lens of {lenses} is monotonic out to the corners of a {image_size} image")
    return K, dist


def project_through_lenses(rig: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points f[N, J, 3] -> (pixels f64[N, C, J, 2], depth f64[N, C, J] mm, undistorted normalized
    radius f64[N, C, J]) through a numpy rig [C] with its distortion, in float64."""
    with jax.enable_x64(True):
        cameras = jax.tree.map(lambda field: jnp.asarray(field, jnp.float64), rig)
        points_camera = world_to_camera(cameras, jnp.asarray(points, jnp.float64)[:, None])  # [N, C, J, 3]
        depth = points_camera[..., 2]
        radius = jnp.linalg.norm(points_camera[..., :2] / jnp.maximum(depth, 1.0)[..., None], axis=-1)
        pixels = project_from_camera(cameras, points_camera)
        return np.asarray(pixels), np.asarray(depth), np.asarray(radius)


def detect_through_lenses(
    rng: np.random.Generator, rig: Cameras, poses: np.ndarray, image_size: tuple[int, int], config: SyntheticConfig
) -> tuple[SimulatedDetections, np.ndarray]:
    """The simulated detector (`simulate_detector` under `config`) on H36M_17 poses f[N, 17, 3] seen
    through the rig's lenses; a joint behind a camera, beyond its lens' monotonic field or outside the
    image (truly or as detected) is missing.  Returns the detections and the exact pixels f64[N, C, J, 2]."""
    clean, depth, radius = project_through_lenses(rig, poses)
    width, height = image_size
    field = monotonic_radius(np.asarray(rig.dist, np.float64))[:, 0]

    def inside(pixels: np.ndarray) -> np.ndarray:
        return (pixels[..., 0] >= 0.0) & (pixels[..., 0] < width) & (pixels[..., 1] >= 0.0) & (pixels[..., 1] < height)

    visible = (depth > 100.0) & (radius < field[:, None]) & inside(clean)
    detections = simulate_detector(rng, np.where(visible[..., None], clean, 0.0), config)
    missing = detections.missing | ~visible | ~inside(detections.keypoints2d)
    return dataclasses.replace(
        detections,
        keypoints2d=np.where(missing[..., None], 0.0, detections.keypoints2d).astype(np.float32),
        confidence=np.where(missing, 0.0, detections.confidence).astype(np.float32),
        outlier=detections.outlier & ~missing,
        missing=missing,
    ), clean
