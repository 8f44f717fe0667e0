"""Calibrated pinhole cameras: the `Cameras` pytree, projection, undistortion, and the lifter input.

Conventions (docs/conventions.md): `x_cam = R @ x_world + t`, t in mm, K the 3x3 intrinsics,
optional distortion `dist = (k1, k2, p1, p2, k3)`.  Every field carries the same leading axes
(usually `[B, C]`: sample, view); functions broadcast those axes against the points' leading axes,
so points of shape `[..., N, 3]` go with cameras of shape `[...]`.

Three distortion models are supported because the real data need them:
- "opencv": the Brown-Conrady model as OpenCV implements it.
- "h36m": the variant Human3.6M's calibration was fitted with (docs/conventions.md), whose tangential
  terms differ from OpenCV's; its `dist` holds (k1, k2, p[0], p[1], k3) in the file's order.
- "fisheye": OpenCV's fisheye (Kannala-Brandt) model, which Anipose/FreeMoCap calibrations write with
  `fisheye = true`: with r the distance of the normalized point from the axis, theta = atan(r),
  theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), and the point is scaled by
  theta_d / r.  Its four coefficients are stored as `dist = (k1, k2, k3, k4, 0)` so that every model
  keeps the 5-vector.  Even with k = 0 this is the equidistant projection, not a pinhole one.

`undistort_points` inverts the "opencv" and "h36m" models by fixed-point iteration and "fisheye" by
Newton's method on theta (the fixed point converges too slowly at the wide angles fisheye lenses see).
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

DistortionModel = Literal["opencv", "h36m", "fisheye"]

# Below this squared radius (normalized units) the fisheye scale theta_d / r uses its Taylor expansion
# 1 + (k1 - 1/3) r^2: the ratio itself is 0/0 at the axis, and `jnp.where` alone would still send NaN
# through the unused branch's gradient.
_FISHEYE_AXIS_R2 = 1e-12

# World and camera coordinates are millimetres; the losses work in metres (see jaxpose.losses).
MM_PER_M = 1000.0


@struct.dataclass
class Cameras:
    """A batch of cameras.  K: [..., 3, 3], R: [..., 3, 3], t: [..., 3] (mm), dist: [..., 5] or None."""

    K: jax.Array
    R: jax.Array
    t: jax.Array
    dist: jax.Array | None = None
    distortion_model: str = struct.field(pytree_node=False, default="opencv")

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.K.shape[:-2])

    def __getitem__(self, index) -> "Cameras":
        """Index the leading axes of every field, e.g. `cameras[:, 0]` is view 0 of every sample."""
        return jax.tree.map(lambda field: field[index], self)

    def without_distortion(self) -> "Cameras":
        return self.replace(dist=None)


def camera_centres(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World positions of the camera centres, `-R^T t`: f64[..., 3] for R [..., 3, 3] and t [..., 3],
    in the unit of t.

    numpy in float64 whatever the inputs (jax arrays included): rig sizes, unit checks and rig
    comparisons are computed once per rig, outside any jitted function, and must not lose float32's digits.
    """
    return -np.einsum("...ji,...j->...i", np.asarray(R, np.float64), np.asarray(t, np.float64))


def world_to_camera(cameras: Cameras, points_world: jax.Array) -> jax.Array:
    """[..., N, 3] world points -> [..., N, 3] camera coordinates (mm)."""
    return jnp.einsum("...ij,...nj->...ni", cameras.R, points_world) + cameras.t[..., None, :]


def camera_to_world(cameras: Cameras, points_camera: jax.Array) -> jax.Array:
    """Inverse of `world_to_camera`."""
    return jnp.einsum("...ji,...nj->...ni", cameras.R, points_camera - cameras.t[..., None, :])


def rotate_between_cameras(source: Cameras, target: Cameras, vectors: jax.Array) -> jax.Array:
    """Rotate direction vectors [..., N, 3] from `source` camera axes to `target` camera axes.

    Root-relative poses are differences of points, so the translation cancels: R_target R_source^T.
    """
    relative = jnp.einsum("...ij,...kj->...ik", target.R, source.R)
    return jnp.einsum("...ij,...nj->...ni", relative, vectors)


def _fisheye_polynomial(theta: jax.Array, dist: jax.Array) -> jax.Array:
    """theta_d / theta = 1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8 (dist = (k1, k2, k3, k4, 0))."""
    k1, k2, k3, k4 = (dist[..., None, i] for i in range(4))
    t2 = theta * theta
    return 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))


def _fisheye_scale(r2: jax.Array, dist: jax.Array) -> jax.Array:
    """theta_d / r for squared radii r2 [..., N], finite with finite gradients at r = 0 (double where)."""
    near_axis = r2 < _FISHEYE_AXIS_R2
    r = jnp.sqrt(jnp.where(near_axis, 1.0, r2))
    theta = jnp.arctan(r)
    far = theta * _fisheye_polynomial(theta, dist) / r
    near = 1.0 + (dist[..., None, 0] - 1.0 / 3.0) * r2
    return jnp.where(near_axis, near, far)


def _distort(xy: jax.Array, dist: jax.Array, model: str) -> jax.Array:
    """Apply lens distortion to normalized image coordinates xy [..., N, 2]."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if model == "fisheye":
        return xy * _fisheye_scale(r2, dist)[..., None]
    k1, k2, p1, p2, k3 = (dist[..., None, i] for i in range(5))
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    if model == "opencv":
        x_d = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        y_d = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    elif model == "h36m":
        tangential = p1 * y + p2 * x
        x_d = x * (radial + tangential) + p2 * r2
        y_d = y * (radial + tangential) + p1 * r2
    else:
        raise ValueError(f"unknown distortion model {model!r}; expected 'opencv', 'h36m' or 'fisheye'")
    return jnp.stack([x_d, y_d], axis=-1)


def _apply_intrinsics(K: jax.Array, xy: jax.Array) -> jax.Array:
    """Normalized coordinates [..., N, 2] -> pixels through K (skew included)."""
    x, y = xy[..., 0], xy[..., 1]
    # Written out rather than as an einsum: XLA on CPU runs a contraction of length 3 as many tiny
    # matrix products, and the losses project [B, C, C', J] points per step.
    u = K[..., 0, 0, None] * x + K[..., 0, 1, None] * y + K[..., 0, 2, None]
    v = K[..., 1, 0, None] * x + K[..., 1, 1, None] * y + K[..., 1, 2, None]
    return jnp.stack([u, v], axis=-1)


def _remove_intrinsics(K: jax.Array, pixels: jax.Array) -> jax.Array:
    """Pixels [..., N, 2] -> normalized image coordinates, solving the upper-triangular K."""
    fx, fy, skew = K[..., 0, 0, None], K[..., 1, 1, None], K[..., 0, 1, None]
    cx, cy = K[..., 0, 2, None], K[..., 1, 2, None]
    y = (pixels[..., 1] - cy) / fy
    x = (pixels[..., 0] - cx - skew * y) / fx
    return jnp.stack([x, y], axis=-1)


def project_from_camera(cameras: Cameras, points_camera: jax.Array, min_depth: float = 1.0) -> jax.Array:
    """Camera-frame points [..., N, 3] (mm) -> pixels [..., N, 2], distortion applied if present.

    Depths below `min_depth` mm are clamped so that a point behind the camera yields a large but
    finite pixel value (and finite gradients) instead of inf/NaN; the data validation rejects such
    geometry in the input, this only protects the losses from wild predictions.
    """
    depth = jnp.maximum(points_camera[..., 2:3], min_depth)
    normalized = points_camera[..., :2] / depth
    if cameras.dist is not None:
        normalized = _distort(normalized, cameras.dist, cameras.distortion_model)
    return _apply_intrinsics(cameras.K, normalized)


def project(cameras: Cameras, points_world: jax.Array) -> jax.Array:
    """World points [..., N, 3] (mm) -> pixels [..., N, 2], with distortion if `cameras.dist` is set."""
    return project_from_camera(cameras, world_to_camera(cameras, points_world))


def projection_matrices(cameras: Cameras) -> jax.Array:
    """Pinhole projection matrices `K [R | t]`: [..., 3, 4] (for undistorted pixels)."""
    extrinsics = jnp.concatenate([cameras.R, cameras.t[..., :, None]], axis=-1)
    return cameras.K @ extrinsics


def project_with_matrices(P: jax.Array, points_world: jax.Array) -> jax.Array:
    """World points [..., J, 3] through every view's `projection_matrices` P [..., C, 3, 4]:
    homogeneous pixels [..., C, J, 3], whose last coordinate is the depth in mm.

    The form the triangulation code works in (it holds P, not the cameras); divide by the depth,
    where it is positive, for undistorted pixels (`project` does that, with distortion, from cameras).
    """
    homogeneous = jnp.concatenate([points_world, jnp.ones_like(points_world[..., :1])], axis=-1)  # [..., J, 4]
    # Broadcast product, not einsum: the leading axes of P and the points may differ in rank (RANSAC).
    return jnp.sum(P[..., :, None, :, :] * homogeneous[..., None, :, None, :], axis=-1)


def undistort_points(cameras: Cameras, pixels: jax.Array, iterations: int = 20) -> jax.Array:
    """Distorted pixels [..., N, 2] -> undistorted pixels, by fixed-point iteration (jittable).

    Solves `distort(x) = x_d` with `x <- x_d - (distort(x) - x)`, which converges for the mild
    distortion of real calibrations (|displacement gradient| < 1 over the image).  The "fisheye"
    model is radial, so it is inverted along the radius instead: Newton's method solves
    theta_d = theta (1 + k1 theta^2 + ...) for theta, and the point is scaled by tan(theta) / theta_d
    (the fixed-point iteration contracts only by r^2 / (1 + r^2) per step there, too slowly at the
    image corners of a wide lens).  Cameras without distortion return the input unchanged.
    """
    if cameras.dist is None:
        return pixels
    return undistort_lens(cameras.K, cameras.dist, pixels, cameras.distortion_model, iterations)


UNDISTORTION_TOLERANCE = 1e-3
"""Normalized image units (about 1 px at a focal length of 1000 px): a point whose undistortion, distorted
again, lands farther than this from where it was detected has no undistorted position (far outside the
image, where the lens polynomial folds back) and comes out NaN, so that it counts as undetected."""


def undistort_lens(K: jax.Array, dist: jax.Array, pixels: jax.Array, model: str = "opencv", iterations: int = 20) -> jax.Array:
    """`undistort_points` of the lens K [..., 3, 3], dist [..., 5] of `model`: pixels [..., N, 2]; NaN
    where the inversion does not converge (`UNDISTORTION_TOLERANCE`)."""
    distorted = _remove_intrinsics(K, pixels)
    if model == "fisheye":
        undistorted = _undistort_fisheye(distorted, dist, iterations)
    else:

        def refine(_, estimate):
            return distorted - (_distort(estimate, dist, model) - estimate)

        undistorted = jax.lax.fori_loop(0, iterations, refine, distorted)
    error = jnp.linalg.norm(_distort(undistorted, dist, model) - distorted, axis=-1)
    converged = (error <= UNDISTORTION_TOLERANCE)[..., None]  # False for NaN too
    return _apply_intrinsics(K, jnp.where(converged, undistorted, jnp.nan))


# `undistort_lens` compiled once per shape and model, the lens an argument: the loaders undistort
# every camera of every recording through it in fixed-size chunks (`jaxpose.chunks`), so that
# neither the number of cameras nor the recordings' lengths add a compilation.
undistort_compiled = jax.jit(undistort_lens, static_argnames=("model", "iterations"))


def _undistort_fisheye(distorted: jax.Array, dist: jax.Array, iterations: int) -> jax.Array:
    """Normalized fisheye-distorted points [..., N, 2] -> undistorted normalized points."""
    r2_d = jnp.sum(distorted * distorted, axis=-1)
    near_axis = r2_d < _FISHEYE_AXIS_R2
    theta_d = jnp.sqrt(jnp.where(near_axis, 1.0, r2_d))
    k1, k2, k3, k4 = (dist[..., None, i] for i in range(4))

    def newton(_, theta):
        t2 = theta * theta
        residual = theta * _fisheye_polynomial(theta, dist) - theta_d
        slope = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
        # A slope near 0 means a model past its turning point (far outside any real image); the
        # clamps keep the iteration finite there and theta inside [0, pi/2), where tan is defined.
        step = residual / jnp.where(jnp.abs(slope) < 1e-6, 1e-6, slope)
        return jnp.clip(theta - step, 0.0, 0.5 * jnp.pi - 1e-4)

    theta = jax.lax.fori_loop(0, iterations, newton, jnp.clip(theta_d, 0.0, 0.5 * jnp.pi - 1e-4))
    # Near the axis tan(theta) / theta_d ~ (1 + theta^2 / 3) / (1 + k1 theta^2) ~ 1 + (1/3 - k1) r_d^2.
    scale = jnp.where(near_axis, 1.0 + (1.0 / 3.0 - k1) * r2_d, jnp.tan(theta) / theta_d)
    return distorted * scale[..., None]


InputNormalization = Literal["intrinsics", "intrinsics_scale", "intrinsics_median"]
INPUT_NORMALIZATIONS: tuple[str, ...] = ("intrinsics", "intrinsics_scale", "intrinsics_median")

# "intrinsics_median": a joint whose distance to the root exceeds this many times the pose's median
# distance is pulled in along its direction to that radius.  On the real Human3.6M S1 poses projected
# into their four cameras (median distance ~92 px), the largest ratio of any joint is 4.3 (training
# trials) / 4.7 (test trials), and the 99.9th percentile of a pose's largest ratio 4.05 / 3.85: the
# limit touches ~0.1% of true poses, and those barely.  A joint pushed hundreds of pixels away arrives
# at this bounded radius, whatever the distance, instead of at a coordinate the network never saw.
MEDIAN_RADIUS_LIMIT = 4.0


def masked_median(values: jax.Array, valid: jax.Array) -> jax.Array:
    """The median of `values` [..., N] over the entries where `valid` [..., N] holds -> [...].

    By comparisons and counts (O(N^2), N is a joint count), not a sort, so that it lowers to the
    elementwise operations every export target has (ONNX included).  The mean of the lower and upper
    medians; 0 where no entry is valid.
    """
    valid = valid.astype(bool)
    # Counts and ranks in floating point: integer division lowers to a `rem` that the ONNX converter
    # cannot take with a symbolic batch axis.
    count = valid.astype(values.dtype).sum(-1, keepdims=True)
    # at_most[..., i] = how many valid values are <= values[..., i]
    at_most = ((values[..., None, :] <= values[..., :, None]) & valid[..., None, :]).astype(values.dtype).sum(-1)
    big = jnp.asarray(jnp.finfo(values.dtype).max, values.dtype)

    def smallest_with(rank):  # the smallest valid value with at least `rank` valid values <= it
        return jnp.where(valid & (at_most >= rank), values, big).min(-1)

    lower = smallest_with(jnp.floor(0.5 * (count + 1.0)))
    upper = smallest_with(jnp.floor(0.5 * count) + 1.0)
    return jnp.where(count[..., 0] > 0, 0.5 * (lower + upper), 0.0)


def normalize_keypoints(
    keypoints2d: jax.Array,
    K: jax.Array,
    confidence: jax.Array | None = None,
    mode: InputNormalization = "intrinsics_median",
    root: int = 0,
) -> jax.Array:
    """One view's 2D pose -> the lifter's input: [..., J, 2] (undistorted pixels) -> [..., J, 2].

    1. Through the intrinsics: pixel -> normalized image coordinate K^-1 [u, v, 1].  This removes the
       focal length, principal point and image size, so a lifter trained on one rig sees the same
       input distribution on another (pixels would tie it to one camera model).
    2. Root-relative: the root (pelvis) is moved to the origin, as the paper does.
    3. With mode "intrinsics_scale", divided by the pose's RMS distance to the root.  What is left of
       the 2D scale is mostly the subject's distance from the camera, which a root-relative 3D pose
       does not depend on; removing it lets the model transfer across subject distances and rigs.
       The 3D output stays metric: the network learns body size from the training poses.
       With mode "intrinsics_median", divided by the MEDIAN of the joints' distances to the root
       instead, and a joint farther than `MEDIAN_RADIUS_LIMIT` medians is pulled in to that radius.
       The RMS is dominated by one far joint: a wrist detected 500 px away makes it several times
       larger and shrinks every other joint of the input towards the root, so the lifter changes
       its whole pose.  One joint moves the median by at most one rank, so the other joints' inputs
       barely change.  Measured on the Human3.6M development lifter (docs/robust_input.md;
       benchmarks/sensitivity.py), a joint moved 500 px beyond an image corner changes the other
       joints' predictions by a median 341 mm with the RMS scale and 216 mm with the median, at the
       same accuracy (P-MPJPE 80.7 / 81.1 mm with the RMS, 81.0 / 81.2 with the median, seeds 0 / 1;
       the supervised twin 54.9 / 55.0; with ground-truth 2D 40.7 / 41.2): the median is the default.
       Inside the image the scale is
       not what moves the other joints (200 px: 124 vs 125 mm): the network mixes every input into
       every output, which `jaxpose.training.config.InputAugmentation` trains against, and `jaxpose.predict`
       lifts a keypoint far outside the image as missing.

    Joints with confidence 0 are set to 0 (and excluded from the scale), so a missing joint never
    injects a garbage coordinate.  A pose whose root is missing gives all zeros; callers mask it.
    """
    normalized = _remove_intrinsics(K, keypoints2d)
    relative = normalized - normalized[..., root : root + 1, :]
    if confidence is None:
        valid = jnp.ones(keypoints2d.shape[:-1], dtype=keypoints2d.dtype)
    else:
        valid = (confidence > 0).astype(keypoints2d.dtype) * (confidence[..., root : root + 1] > 0)
    relative = jnp.where(valid[..., None] > 0, relative, 0.0)  # `where`: a missing joint may hold NaN
    if mode == "intrinsics_scale":
        count = jnp.maximum(valid.sum(-1, keepdims=True) - 1.0, 1.0)
        mean_square = (relative**2).sum((-2, -1))[..., None] / count
        relative = relative / jnp.sqrt(mean_square + 1e-12)[..., None]
    elif mode == "intrinsics_median":
        distance = jnp.sqrt((relative**2).sum(-1) + 1e-24)
        others = (valid > 0) & (jnp.arange(valid.shape[-1]) != root)
        scale = masked_median(distance, others)[..., None]
        ratio = distance / jnp.maximum(scale, 1e-12)
        pull = jnp.minimum(1.0, MEDIAN_RADIUS_LIMIT / jnp.maximum(ratio, 1e-12))
        relative = relative * (pull / jnp.maximum(scale, 1e-12))[..., None]
    elif mode != "intrinsics":
        raise ValueError(f"unknown input normalization {mode!r}; expected one of {INPUT_NORMALIZATIONS}")
    return relative
