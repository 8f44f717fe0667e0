"""Multi-view 3D motion: the triangulation's evidence and every view's lifted pose in one estimate.

The model, per instant (world frame, millimetres).  Unknowns: the joints X_j and, for every view c
whose pose was lifted, where that lift stands in the world: its root T_c and its scale s_c.  The lift
L_cj (root-relative, in camera c's axes, `Lifter3D.predict`'s output) says X_j ~ T_c + s_c R_c^T L_cj.
Every piece of evidence is a squared residual over its variance, so the minimum is the estimate of a
Gaussian model and the inverse of its normal matrix the posterior covariance:

- A detection u_cj (confidence w_cj > 0): the distance (mm) of X_j from view c's ray through u_cj,
  weighted by (w_cj f_c / (z_cj pixel_sigma))^2.  At depth z a distance d is d f / z pixels, so this is
  the reprojection error to first order, yet linear in X (the midpoint form of triangulation).  The
  confidence scales the residual, as in the confidence-weighted DLT of the pseudo-labels.
- A lifted joint: X_j - T_c - s_c R_c^T L_cj, with covariance R_c^T diag(l^2, l^2, d^2) R_c in world
  axes (l = `lift_lateral_mm`, d = `lift_depth_mm`).  A lifter sees the 2D it lifts, so its error
  should lie along its camera's optical axis far more than across it; then one camera's precise
  lateral directions fix another's uncertain depth.  The translation T_c is free, so a lift only
  ever says where the joints are relative to each other.
- s_c ~ N(1, scale_sigma^2): a lifter's idea of body size is off by some percent, which the views
  measure where they see joints; with one view, scale and depth are one unknown and the prior decides.
- N(0, (30 km)^2) on every position: it moves no determined value, but keeps the normal matrix
  invertible where the evidence leaves a direction free (a joint one view sees, with no lift); such a
  joint's uncertainty then exceeds `UNOBSERVABLE_MM` and it is reported missing.

Robust, as the pseudo-labels are (`jaxpose.robust`): iteratively re-weighted.  Each detection's weight
is multiplied by the Cauchy weight of its reprojection error (pixels), each lifted joint's by the
Cauchy weight of its Mahalanobis residual (in standard deviations); the last solve keeps only the
detections within `agree_px` (as `robust.refine_on_inliers` does) and the lifted joints within
`lift_agree_sigmas`: a Cauchy weight alone still lets a swapped limb's lift, a metre off, bend a
joint that two exact views see by millimetres (median 2.9 mm, up to 19 mm on 67 random rigs; with the
cut, < 0.001 mm).  The detections are solved alone first (the same re-weighting, no lifts): a robust
triangulation, by which each view's lift is judged once.  Placed on the joints that two agreeing views
fix there, a lift gets a trust, the Cauchy weight of its median residual, that scales all its joints'
weights from then on: an untrained lifter's poses (a third of the body's size, 340 mm off) then move
the example project's joints by 4 mm on average instead of by 300 (their pull drew the joints off the
rays, whose Cauchy weights then let go).  A lift that fits keeps its full weight, and the lifted poses,
placed by all the other joints, hold a joint that just two disagreeing views see (or two views that
agree on a wrong point along their epipolar line) until the Cauchy weights let go of the wrong view.

Provenance, from the final estimate: TRIANGULATED where at least two views agree (within `agree_px`),
FUSED where one does (its ray fixes two directions, the lifts the depth), LIFTED where none does
(the lifts alone, placed by the other joints), NONE where nothing fixes the joint (NaN).
Uncertainty: sqrt(trace) of the joint's posterior covariance, an RMS 3D error (mm) under the model.

The defaults are near the simulator's detector (3-8 px) and a lifter of ~50 mm error; they are
to be measured on Human3.6M.  tests/reconstruction/test_fusion.py measures the alternatives on
simulated data with joints seen by 0, 1, 2 and 3+ views: plain DLT, the same fusion without lifts,
the most confident view's lift alone, the mean of the placed lifts, an isotropic lift error, a fixed
lift scale; the fusion is the most accurate of them in every bucket.

The solve: the placements (T_c, s_c) of different views share no term, so they are eliminated (Schur
complement, a 4x4 inverse per view) and a 3J x 3J system in the joints solved, its matrix a sum of one
term per view: linear in the number of views (the joints eliminated instead leave a 4C x 4C system,
cubic in them: at 32 views, 100 instants took 2.5 s of CPU that way, 0.5 s this way).  The
detections-alone stage has no placements: a 3x3 system per joint.  Batched numpy in float64 over the
instants.  Float64 because the normal equations square the conditioning, and a depth that only a
lift's shape fixes (one view) is poorly conditioned: float32 would not keep the 1e-3 mm of exact data.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.robust import BEHIND_CAMERA_PX, DEFAULT_IRLS_SCALE_PX, DEFAULT_THRESHOLD_PX, cauchy_weights

PRIOR_PRECISION = 1e-15  # 1 / mm^2: the N(0, (30 km)^2) on every position
UNOBSERVABLE_MM = 1e4  # a joint the evidence does not fix within 10 m is missing
START_DEPTH_MM = 4000.0  # the depth that weighs the rays of the first solve, before any is known
MIN_FITTED_JOINTS = 2  # a lift's root and scale (4 unknowns) are fitted to the triangulated joints from 2 on
MIN_DEPTH_MM = 1.0  # nearer than this (or behind) a camera, a point is no projection of what it saw
CHUNK_VIEWS = 1024  # instants x views per batched solve: cache-sized (250 instants of 16 views: 0.38 s of CPU in
# chunks of 64 instants, 0.43 s in chunks of 256; of 4 views the same either way)
CHUNK_LIMITS = (64, 256)  # the fewest and the most instants per chunk


class Provenance(enum.IntEnum):
    """Where a joint's position comes from (module docstring)."""

    NONE = 0
    LIFTED = 1
    FUSED = 2
    TRIANGULATED = 3
    INTERPOLATED = 4  # never from `fuse`: a gap bridged by `jaxpose.formats.gaps.fill_gaps`


@dataclasses.dataclass(frozen=True)
class FusionConfig:
    """The model's standard deviations and the robust loss (module docstring)."""

    pixel_sigma: float = 4.0
    """A detection's error per image coordinate (px) at confidence 1."""
    lift_lateral_mm: float = 40.0
    """The lifter's error per coordinate across its camera's optical axis (mm)."""
    lift_depth_mm: float = 70.0
    """The lifter's error along its camera's optical axis (mm)."""
    scale_sigma: float = 0.05
    """The spread of the lifter's body size, relative (0.05 = 5%)."""
    robust_scale_px: float = DEFAULT_IRLS_SCALE_PX
    """The Cauchy scale of the reprojection errors (px)."""
    lift_robust_sigmas: float = 3.0
    """The Cauchy scale of the lifted joints' residuals (standard deviations)."""
    lift_agree_sigmas: float = 5.0
    """A lifted joint agrees with the estimate within this Mahalanobis residual (standard deviations)."""
    agree_px: float = DEFAULT_THRESHOLD_PX
    """A view agrees with a joint within this reprojection error (px)."""
    iterations: int = 5
    """Re-weighted solves after the first (the last keeps only the agreeing evidence)."""

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"FusionConfig.{field.name} must be a positive number, got {value!r}")
        if not isinstance(self.iterations, int):
            raise ValueError(f"FusionConfig.iterations must be a whole number, got {self.iterations!r}")


@dataclasses.dataclass(frozen=True)
class Fusion:
    """The fused motion of N instants, J joints, C views.

    points:      f32[N, J, 3] world mm; NaN where the provenance is NONE.
    provenance:  i8[N, J] `Provenance`.
    uncertainty: f32[N, J] mm, the posterior RMS 3D error; NaN where NONE.
    views:       i8[N, J] detections that agree with the joint (within `agree_px`).
    placement:   f32[N, C, 4] each lifted view's root (world mm) and scale; NaN for a view whose lift
                 did not count (none, or none of its joints agreed).
    covariance:  f32[N, J, 3, 3] mm^2, each joint's posterior covariance (its trace is uncertainty^2); a
                 joint kept at the mean of disagreeing lifts gets an isotropic one; NaN where NONE.  What
                 `jaxpose.reconstruction.trajectory` weighs each instant's evidence by.
    """

    points: np.ndarray
    provenance: np.ndarray
    uncertainty: np.ndarray
    views: np.ndarray
    placement: np.ndarray
    covariance: np.ndarray


def fuse(
    cameras: Cameras,
    keypoints2d: np.ndarray,
    confidence: np.ndarray,
    lifted: np.ndarray | None,
    config: FusionConfig = FusionConfig(),
    chunk_size: int | None = None,
) -> Fusion:
    """The world-frame joints of N instants from C views (module docstring).

    cameras:     pinhole `Cameras` (dist None: undistort the keypoints first), fields [C, ...] for one
                 rig or [N, C, ...]; x_cam = R x_world + t, t in mm.
    keypoints2d: [N, C, J, 2] undistorted pixels; anything where the confidence is 0 (NaN included).
    confidence:  [N, C, J] in [0, 1]; 0 = not seen.
    lifted:      [N, C, J, 3] mm, each view's root-relative lift in its camera's axes; NaN where a view
                 (or joint) has none.  None = no lifts: a robust triangulation of the detections alone.
    chunk_size:  instants per batched solve (the instants are independent); None = `CHUNK_VIEWS` / C
                 within `CHUNK_LIMITS`.
    """
    keypoints2d = np.asarray(keypoints2d, np.float64)
    confidence = np.asarray(confidence, np.float64)
    if keypoints2d.ndim != 4 or keypoints2d.shape[-1] != 2:
        raise ValueError(f"fuse: keypoints2d must be [N, C, J, 2], got shape {keypoints2d.shape}")
    N, C, J, _ = keypoints2d.shape
    if confidence.shape != (N, C, J):
        raise ValueError(f"fuse: confidence must be [N, C, J] = {(N, C, J)}, got shape {confidence.shape}")
    lifted = np.full((N, C, J, 3), np.nan) if lifted is None else np.asarray(lifted, np.float64)
    if lifted.shape != (N, C, J, 3):
        raise ValueError(f"fuse: lifted must be [N, C, J, 3] = {(N, C, J, 3)}, got shape {lifted.shape}")
    if cameras.dist is not None and np.any(np.asarray(cameras.dist) != 0):
        raise ValueError(
            "fuse: the cameras have lens distortion; undistort the keypoints and pass cameras.without_distortion()"
        )
    fields = []
    for name, tail in (("K", (3, 3)), ("R", (3, 3)), ("t", (3,))):
        field = np.asarray(getattr(cameras, name), np.float64)
        if field.shape not in ((C, *tail), (N, C, *tail)):
            expected = f"[C, {', '.join(map(str, tail))}] or [N, C, ...] with C = {C}, N = {N}"
            raise ValueError(f"fuse: cameras.{name} must be {expected}, got shape {field.shape}")
        fields.append(np.broadcast_to(field, (N, C, *tail)))
    if N == 0:
        raise ValueError("fuse: no instants (keypoints2d has shape [0, ...])")
    rows = [*fields, keypoints2d, confidence, lifted]
    # Chunks of exactly `chunk_size` instants, the last one shorter: numpy, unlike a jitted function, gains
    # nothing from padding it to a fixed shape.
    chunk_size = chunk_size or int(np.clip(CHUNK_VIEWS // C, *CHUNK_LIMITS))
    parts = [_fuse_rows(*(row[start : start + chunk_size] for row in rows), config=config) for start in range(0, N, chunk_size)]
    return Fusion(*(np.concatenate(field) for field in zip(*parts)))


@dataclasses.dataclass(frozen=True)
class _Evidence:
    """The fixed terms of one chunk of n instants (float64), joint-major where summed over views."""

    projection: np.ndarray  # [n, C, 3, 3]: (K R)^T, world points as rows to homogeneous pixels (depth last)
    offset: np.ndarray  # [n, C, 1, 3]: K t
    keypoints: np.ndarray  # [n, C, J, 2], 0 where unseen
    seen: np.ndarray  # bool[n, C, J]
    ray_scale: np.ndarray  # [n, C, J]: (w f / pixel_sigma)^2, a ray's weight times its depth squared
    rays: np.ndarray  # [n, J, C, 3]: the unit ray d of each detection (world axes)
    projected_centre: np.ndarray  # [n, J, C, 3]: (I - d d^T) o, o the camera centre
    lifted: np.ndarray  # bool[n, C, J]
    lift: np.ndarray  # [n, C, J, 3]: R^T L, the lifts in world axes (0 where none)
    precision: np.ndarray  # [n, C, 3, 3]: P, the inverse of a lifted joint's covariance (world axes)
    precision_lift: np.ndarray  # [n, C, J, 3]: P R^T L
    lift_energy: np.ndarray  # [n, C, J]: (R^T L)^T P R^T L


def _evidence(K, R, t, keypoints, confidence, lifted, config: FusionConfig) -> _Evidence:
    n, C, J, _ = keypoints.shape
    seen = (confidence > 0) & np.isfinite(confidence) & np.isfinite(keypoints).all(-1)
    keypoints = np.where(seen[..., None], keypoints, 0.0)
    homogeneous = np.concatenate([keypoints, np.ones((n, C, J, 1))], -1)
    # Points as rows, (R^T K^-1 h)^T = h^T K^-T R: batched matrix products, far faster than einsum here.
    rays = homogeneous @ (np.linalg.inv(K).swapaxes(-1, -2) @ R)
    rays = (rays / np.linalg.norm(rays, axis=-1, keepdims=True)).swapaxes(1, 2)
    centres = -(t[:, None, :, None, :] @ R[:, None])[..., 0, :]  # -R^T t: [n, 1, C, 3]
    projected_centre = centres - rays * np.sum(rays * centres, -1, keepdims=True)
    focal = 0.5 * (K[..., 0, 0] + K[..., 1, 1])
    ray_scale = np.where(seen, (confidence * focal[..., None] / config.pixel_sigma) ** 2, 0.0)
    is_lifted = np.isfinite(lifted).all(-1)
    lift = np.where(is_lifted[..., None], lifted, 0.0) @ R  # R^T L
    axes = 1.0 / np.array([config.lift_lateral_mm, config.lift_lateral_mm, config.lift_depth_mm]) ** 2
    precision = (R.swapaxes(-1, -2) * axes) @ R
    precision_lift = lift @ precision  # P symmetric
    return _Evidence(
        (K @ R).swapaxes(-1, -2), (K @ t[..., None]).swapaxes(-1, -2), keypoints, seen, ray_scale, rays, projected_centre,
        is_lifted, lift, precision, precision_lift, np.sum(precision_lift * lift, -1),
    )  # fmt: skip


def _reproject(ev: _Evidence, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixel error [n, C, J], depth [n, C, J]) of world points [n, J, 3]; BEHIND_CAMERA_PX when behind."""
    homogeneous = points[:, None] @ ev.projection + ev.offset  # K (R x + t): its last coordinate is the depth
    depth = homogeneous[..., 2]
    front = depth > MIN_DEPTH_MM
    pixels = homogeneous[..., :2] / np.where(front, depth, 1.0)[..., None]
    error = np.sqrt(np.sum((pixels - ev.keypoints) ** 2, -1))
    return np.where(front, error, BEHIND_CAMERA_PX), depth


def _ray_weights(ev: _Evidence, points: np.ndarray, config: FusionConfig, agreeing_only: bool) -> np.ndarray:
    """[n, C, J]: each detection's weight at `points`: (w f / (z sigma))^2 x Cauchy(reprojection error)."""
    error, depth = _reproject(ev, points)
    usable = ev.seen & (depth > MIN_DEPTH_MM)
    if agreeing_only:
        usable &= error <= config.agree_px
    weight = ev.ray_scale * cauchy_weights(error, config.robust_scale_px) / np.where(usable, depth, 1.0) ** 2
    return np.where(usable, weight, 0.0)


def _placed_lifts(ev: _Evidence, placement: np.ndarray) -> np.ndarray:
    """[n, C, J, 3]: each view's lift where `placement` [n, C, 4] (root T_c, scale s_c) puts it, T_c + s_c R_c^T L_c."""
    return placement[:, :, None, :3] + placement[:, :, None, 3:] * ev.lift


def _lift_mahalanobis(ev: _Evidence, points: np.ndarray, placement: np.ndarray) -> np.ndarray:
    """[n, C, J]: each lifted joint's Mahalanobis residual (standard deviations) from `points` [n, J, 3]."""
    residual = points[:, None] - _placed_lifts(ev, placement)
    return np.sqrt(np.sum((residual @ ev.precision) * residual, -1))


def _lift_weights(ev: _Evidence, points, placement, config: FusionConfig, agreeing_only: bool) -> np.ndarray:
    """[n, C, J]: the Cauchy weight of each lifted joint's Mahalanobis residual at `points` [n, J, 3] and
    `placement` [n, C, 4], 0 where not lifted (or, `agreeing_only`, beyond `lift_agree_sigmas`)."""
    mahalanobis = _lift_mahalanobis(ev, points, placement)
    usable = ev.lifted & (mahalanobis <= config.lift_agree_sigmas) if agreeing_only else ev.lifted
    return np.where(usable, cauchy_weights(mahalanobis, config.lift_robust_sigmas), 0.0)


def _lift_trust(ev: _Evidence, points: np.ndarray, fixed: np.ndarray, config: FusionConfig) -> np.ndarray:
    """[n, C]: how much each view's lift counts, a factor on all its joints' weights.  A lift with at least
    `MIN_FITTED_JOINTS` joints that the detections alone fix (bool `fixed` [n, J], at `points` [n, J, 3])
    is placed on them (T_c, s_c, with the scale prior) by least squares, then again on the better half of
    them (a joint two views put metres off, where they happen to agree, must not move the placement): its
    trust is the Cauchy weight of the median Mahalanobis residual.  A lift that does not fit the
    triangulated body (an untrained lifter's poses are a third of the body's size) then cannot pull the
    joints off the rays, whose Cauchy weights would let go of them; one that fits counts fully, even where
    two views agree on a wrong point (along their epipolar line).  Other lifts: 1 (the detections fix too
    little to judge them, and the lift is the evidence there)."""
    fitted = (ev.lifted & fixed[:, None]).astype(np.float64)  # [n, C, J]
    count = fitted.sum(-1).astype(np.int64)  # [n, C]
    weight = fitted
    for _ in range(2):
        median, mahalanobis = _fitted_residuals(ev, points, weight, fitted, count, config)
        weight = fitted * (mahalanobis <= median[..., None])
    return cauchy_weights(np.where(count >= MIN_FITTED_JOINTS, median, 0.0), config.lift_robust_sigmas)


def _fitted_residuals(ev: _Evidence, points, weight, fitted, count, config: FusionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Each lift placed on `points` [n, J, 3] by least squares over the joints of `weight` [n, C, J] ->
    (the median Mahalanobis residual of the joints of `fitted` [n, C], the residuals [n, C, J])."""
    A = np.zeros((*weight.shape[:2], 4, 4))
    A[..., :3, :3] = weight.sum(-1)[..., None, None] * ev.precision + PRIOR_PRECISION * np.eye(3)
    A[..., :3, 3] = A[..., 3, :3] = np.sum(weight[..., None] * ev.precision_lift, 2)
    A[..., 3, 3] = np.sum(weight * ev.lift_energy, -1) + 1.0 / config.scale_sigma**2
    b = np.zeros((*weight.shape[:2], 4))
    b[..., :3] = (ev.precision @ (weight @ points)[..., None])[..., 0]
    b[..., 3] = np.sum(weight * np.sum(ev.precision_lift * points[:, None], -1), -1) + 1.0 / config.scale_sigma**2
    placement = np.linalg.solve(A, b[..., None])[..., 0]
    mahalanobis = _lift_mahalanobis(ev, points, placement)
    order = np.sort(np.where(fitted > 0, mahalanobis, np.inf), -1)  # the fitted joints' residuals first
    lower = np.take_along_axis(order, (np.maximum(count, 1) - 1)[..., None] // 2, -1)[..., 0]
    upper = np.take_along_axis(order, np.maximum(count, 1)[..., None] // 2, -1)[..., 0]
    return 0.5 * (lower + upper), mahalanobis


def _joint_system(ev: _Evidence, rays: np.ndarray, lifts: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's own blocks of the normal equations, ([n, J, 3, 3], [n, J, 3]): the sum over views of
    w (I - d d^T) (+ lambda P where `lifts` [n, C, J] are given) and of w (I - d d^T) o."""
    n, C, J = rays.shape
    rays = rays.swapaxes(1, 2)  # [n, J, C]
    matrix = (rays.sum(-1) + PRIOR_PRECISION)[..., None, None] * np.eye(3) - (rays[..., None] * ev.rays).swapaxes(-1, -2) @ ev.rays
    if lifts is not None:
        matrix = matrix + (lifts.swapaxes(1, 2) @ ev.precision.reshape(n, C, 9)).reshape(n, J, 3, 3)
    return matrix, (rays[:, :, None] @ ev.projected_centre)[:, :, 0]


def _triangulate(ev: _Evidence, rays: np.ndarray) -> np.ndarray:
    """[n, J, 3]: the detections alone (ray weights [n, C, J]), each joint its own 3x3 system."""
    matrix, rhs = _joint_system(ev, rays, None)
    return np.linalg.solve(matrix, rhs[..., None])[..., 0]


def _solve(ev: _Evidence, rays: np.ndarray, lifts: np.ndarray, config: FusionConfig, covariance: bool = False):
    """The weighted least squares (module docstring) -> (points [n, J, 3], placement [n, C, 4], and
    with `covariance` the joints' covariances [n, J, 3, 3]), the placements eliminated first.

    A lift predicts G (T, s) with G = [I | R^T L], so its blocks are P G = [P | P R^T L] and
    G^T P G.  The placements of different views share no term: their block is block-diagonal (one 4x4
    per view), so eliminating them (Schur complement) leaves a dense 3J x 3J system in the joints, a sum
    of one rank-4 term per view: the work grows linearly with the views (eliminating the joints instead
    leaves a dense 4C x 4C system, cubic in them).  The joints' block of the inverse is that system's
    inverse, so their posterior covariances are its diagonal blocks."""
    n, C, J = rays.shape
    joint_matrix, joint_rhs = _joint_system(ev, rays, lifts)
    weighted_lift = lifts[..., None] * ev.precision_lift  # [n, C, J, 3]
    # Per view, its coupling's transpose [n, C, 4, 3J]: the rows of T_c (lambda P) and s_c (lambda P R^T L)
    # against the joints' coordinates (index 3 j + axis), contiguous so that the sum over views is one product.
    coupling = np.empty((n, C, 4, J, 3))
    np.multiply(lifts[:, :, None, :, None], ev.precision[:, :, :, None, :], out=coupling[:, :, :3])
    coupling[:, :, 3] = weighted_lift
    coupling = coupling.reshape(n, C, 4, 3 * J)
    placement_matrix = np.zeros((n, C, 4, 4))
    placement_matrix[..., :3, :3] = lifts.sum(-1)[..., None, None] * ev.precision
    placement_matrix[..., :3, 3] = placement_matrix[..., 3, :3] = weighted_lift.sum(2)
    placement_matrix[..., 3, 3] = np.sum(lifts * ev.lift_energy, -1)
    prior = np.array([PRIOR_PRECISION] * 3 + [1.0 / config.scale_sigma**2])
    placement_inverse = np.linalg.inv(placement_matrix + np.diag(prior))  # [n, C, 4, 4]
    reduced = placement_inverse @ coupling  # [n, C, 4, 3J]
    matrix = -(reduced.reshape(n, 4 * C, 3 * J).swapaxes(-1, -2) @ coupling.reshape(n, 4 * C, 3 * J))
    joint = np.arange(J)
    matrix.reshape(n, J, 3, J, 3)[:, joint, :, joint] += joint_matrix.swapaxes(0, 1)  # each joint's own block
    rhs = joint_rhs.reshape(n, 3 * J) + reduced[:, :, 3].sum(1) * prior[3]  # the scale prior's pull, N(1, sigma)
    if covariance:
        inverse = np.linalg.inv(matrix)
        points = (inverse @ rhs[..., None])[..., 0]
    else:
        points = np.linalg.solve(matrix, rhs[..., None])[..., 0]
    placement_rhs = (coupling @ points[:, None, :, None])[..., 0] + prior * [0, 0, 0, 1]  # [n, C, 4]
    placement = (placement_inverse @ placement_rhs[..., None])[..., 0]
    points = points.reshape(n, J, 3)
    if not covariance:
        return points, placement
    return points, placement, inverse.reshape(n, J, 3, J, 3)[:, joint, :, joint].swapaxes(0, 1)


def _disagreeing_lifts(ev: _Evidence, points, placement, spread, known, trust, config: FusionConfig):
    """(points, spread, known) with each joint that nothing fixed (no detection, and its lifts cut for
    disagreeing beyond `lift_agree_sigmas`) put at the trust-weighted mean of its placed lifts (placement
    [n, C, 4], NaN for a view whose lift did not count), with an uncertainty of the lift's error and the
    lifts' spread: views whose lifts disagree there leave the joint lifted, not missing.  Added after the
    solve, so that such a joint moves neither the placements nor the other joints."""
    placed = _placed_lifts(ev, placement)
    counted = ev.lifted & np.isfinite(placed).all(-1) & (trust[..., None] > 0)
    weight = np.where(counted, trust[..., None], 0.0)  # [n, C, J]
    fill = ~known & counted.any(1)
    total = np.maximum(weight.sum(1), 1e-12)[..., None]  # [n, J, 1]
    mean = np.sum(weight[..., None] * np.where(counted[..., None], placed, 0.0), 1) / total
    scatter = np.sum(weight * np.sum((np.where(counted[..., None], placed, 0.0) - mean[:, None]) ** 2, -1), 1) / total[..., 0]
    lift_error = np.sqrt(2 * config.lift_lateral_mm**2 + config.lift_depth_mm**2)
    return (
        np.where(fill[..., None], mean, points),
        np.where(fill, np.sqrt(lift_error**2 + scatter), spread),
        known | fill,
    )


def _fuse_rows(K, R, t, keypoints, confidence, lifted, *, config: FusionConfig):
    """`fuse` on one chunk of instants: the tuple of `Fusion`'s fields."""
    ev = _evidence(K, R, t, keypoints, confidence, lifted, config)
    # The detections alone first (their robust triangulation), by which each lift is judged (`_lift_trust`).
    rays = ev.ray_scale / START_DEPTH_MM**2
    for _ in range(config.iterations):
        points = _triangulate(ev, rays)
        rays = _ray_weights(ev, points, config, agreeing_only=False)
    error, _ = _reproject(ev, points)
    fixed = (ev.seen & (error <= config.agree_px)).sum(1) >= 2  # [n, J]: joints the detections fix alone
    trust = _lift_trust(ev, points, fixed, config)[..., None]
    # Then the first solve of all the evidence as if nothing were known (confidence alone; the lifts by trust).
    points, placement = _solve(ev, ev.ray_scale / START_DEPTH_MM**2, ev.lifted * trust, config)
    for iteration in range(1, config.iterations + 1):
        last = iteration == config.iterations
        rays = _ray_weights(ev, points, config, agreeing_only=last)
        lifts = _lift_weights(ev, points, placement, config, agreeing_only=last) * trust
        points, placement, *covariance = _solve(ev, rays, lifts, config, covariance=last)
    error, _ = _reproject(ev, points)
    views = (ev.seen & (error <= config.agree_px)).sum(1)
    spread = np.sqrt(np.trace(covariance[0], axis1=-2, axis2=-1))
    known = spread <= UNOBSERVABLE_MM
    placement = np.where(lifts.any(-1)[..., None], placement, np.nan)  # views whose lift counted
    solved = known
    points, spread, known = _disagreeing_lifts(ev, points, placement, spread, known, trust[..., 0], config)
    isotropic = (spread**2 / 3.0)[..., None, None] * np.eye(3)
    covariance = np.where((known & ~solved)[..., None, None], isotropic, covariance[0])
    provenance = np.select(
        [~known, views >= 2, views == 1], [Provenance.NONE, Provenance.TRIANGULATED, Provenance.FUSED], Provenance.LIFTED
    )
    return (
        np.where(known[..., None], points, np.nan).astype(np.float32),
        provenance.astype(np.int8),
        np.where(known, spread, np.nan).astype(np.float32),
        views.astype(np.int8),
        placement.astype(np.float32),
        np.where(known[..., None, None], covariance, np.nan).astype(np.float32),
    )
