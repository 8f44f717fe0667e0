"""Recover a multi-camera rig from the person it films: no calibration target, no calibration file.

    from jaxpose.calibration import CalibrationConfig, calibrate, read_detections_npz
    calibration = calibrate(read_detections_npz("detections.npz"), CalibrationConfig())
    calibration.cameras          # Cameras [C]: K, R, t (mm), dist as given

The steps, each its own module:
1. `inputs`: the detections (an npz, or a subject of a loaded data set) and their checks; with several
   people per view, `matching` first pairs them across views by their epipolar geometry (one row per person);
2. here: frame selection, undistortion with the known intrinsics (or an image-size guess of them, no
   distortion) for the first rig, a check that the person moves enough to calibrate on;
3. `initial`: a first rig from one view pair's essential matrix and PnP for the other views (OpenCV);
4. `bundle`: bundle adjustment of all cameras over all joints (JAX), with the unknown intrinsics
   (focal length, principal point, radial distortion; `lens`: which are free, their priors and the
   1-sigma of each);
5. `scale`: metric scale from the limb lengths of the person.

World frame of the result: view 0's camera frame (origin at its centre, x right, y down, z along
its optical axis), millimetres.  `compare` measures a result against a reference calibration.
"""

from __future__ import annotations

import importlib.util

_MISSING = [name for name in ("cv2", "optimistix", "jaxlie") if importlib.util.find_spec(name) is None]
if _MISSING:
    raise ImportError(f"jaxpose.calibration needs {_MISSING}: pip install 'jaxpose[calibrate]'")

import dataclasses
import time
import warnings

import numpy as np

from jaxpose.calibration.bundle import bundle_adjust
from jaxpose.calibration.compare import RigComparison, compare_rigs
from jaxpose.calibration.initial import CalibrationError, initial_rig, triangulate_and_project
from jaxpose.calibration.inputs import RigDetections, from_dataset, read_detections_npz
from jaxpose.calibration.lens import INTRINSICS, LensConfig, LensEstimate, LensSetup, lens_setup
from jaxpose.calibration.scale import DEFAULT_LIMB_LENGTHS_MM, MetricScale, metric_scale
from jaxpose.calibration.world import WorldFrame
from jaxpose.camera import Cameras, undistort_compiled

__all__ = [
    "INTRINSICS", "Calibration", "CalibrationConfig", "CalibrationError", "LensConfig", "LensEstimate", "RigComparison",
    "RigDetections", "calibrate", "compare_rigs", "from_dataset", "read_detections_npz",
]  # fmt: skip

WORLD_FRAME = "view 0's camera frame (origin at its centre, x right, y down, z forward), millimetres"
# Focal length guessed from the image size when the intrinsics are unknown (a common starting
# point of structure-from-motion tools; bundle adjustment then estimates the real one).
FOCAL_GUESS_PER_IMAGE_SIDE = 1.2
# The focal lengths (x the longer image side) the first rig is tried with when they are unknown:
# from a 120-degree wide-angle lens (0.3) to a 37-degree one (1.5), the guess among them.
FOCAL_CANDIDATES = tuple(sorted({*np.geomspace(0.3, 1.5, 8).round(3).tolist(), FOCAL_GUESS_PER_IMAGE_SIDE}))


@dataclasses.dataclass(frozen=True)
class CalibrationConfig:
    """How the rig is recovered."""

    limb_lengths_mm: tuple[float, float, float, float] = DEFAULT_LIMB_LENGTHS_MM
    """Metric scale prior: the subject's upper arm, forearm, thigh and shank (mm, joint centre to joint centre)."""
    max_frames: int = 600
    """Frames used, spread evenly over the input: the adjustment's time grows with them (600: ~25 s
    on 2 cores), its accuracy hardly (on the synthetic rig 1500 gave 0.05 degrees where 600 gave 0.08)."""
    min_confidence: float = 0.3
    """Keypoints with a lower confidence are treated as not detected."""
    min_joints: int = 6
    """A view sees the person in a frame when at least this many joints are detected."""
    min_frames: int = 30
    """Frames in which two views both see the person, needed to relate them."""
    ransac_threshold_px: float = 8.0
    """Inlier distance of the initial RANSAC estimates (pixels)."""
    min_motion: float = 0.01
    """Refuse a person who barely moves: the median over joints and views of the keypoints' spread
    over time must exceed this fraction of the image diagonal."""
    estimate_focal: bool | None = None
    """Estimate the focal lengths: None = only when the input gives no intrinsics K."""
    lens: LensConfig = LensConfig()
    """The other intrinsics: which unknown ones are estimated (principal point, distortion) and their priors."""
    robust_rounds: int = 4
    """Re-weighting rounds of the bundle adjustment (each down-weights outlying detections anew)."""
    seed: int = 0
    """Seed of the RANSAC estimates and of their correspondence subsets."""

    def __post_init__(self):
        for name in ("max_frames", "min_joints", "min_frames", "robust_rounds"):
            if getattr(self, name) < 1:
                raise ValueError(f"calibration {name} must be >= 1, got {getattr(self, name)}")
        if self.ransac_threshold_px <= 0 or len(self.limb_lengths_mm) != 4 or min(self.limb_lengths_mm) <= 0:
            raise ValueError("calibration ransac_threshold_px and the four limb_lengths_mm must be positive")


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A recovered rig and how well it explains the detections."""

    cameras: Cameras
    """numpy `Cameras` [C]: K, R, t (mm, world = `WORLD_FRAME`), dist: the input's, or estimated ("opencv"
    model), or None (pinhole: neither given nor estimated)."""
    camera_names: tuple[str, ...]
    image_size: np.ndarray
    reprojection_median_px: np.ndarray
    """f64[C] median re-projection error of every used detection (outliers included)."""
    reprojection_p90_px: np.ndarray
    """f64[C] its 90th percentile."""
    inlier_fraction: np.ndarray
    """f64[C] the share of detections the robust adjustment kept (weight > 0.5)."""
    scale: MetricScale
    focal_estimated: bool
    lens: LensEstimate
    """Every camera's intrinsics with their 1-sigma, and which were given, estimated or left at their prior."""
    residual_scale: float
    """The adjustment's robust residual variance factor (near 1 when the per-joint noise levels explain the residuals)."""
    frames_used: int
    seconds: float
    world: WorldFrame | None = None
    """The world the cameras are in: None = view 0's camera frame (`WORLD_FRAME`, as `calibrate` leaves
    them); else the upright metric world this similarity moved them into (`jaxpose.calibration.world.to_world`),
    so that whatever writes the rig states the world it is in."""


def _select_frames(valid: np.ndarray, config: CalibrationConfig) -> np.ndarray:
    """Indices of frames where >= 2 views see the person, at most `max_frames`, evenly spread."""
    usable = np.flatnonzero((valid.sum(-1) >= config.min_joints).sum(-1) >= 2)
    if len(usable) > config.max_frames:
        usable = usable[np.linspace(0, len(usable) - 1, config.max_frames).round().astype(int)]
    return usable


def _check_motion(pixels: np.ndarray, valid: np.ndarray, detections: RigDetections, config: CalibrationConfig) -> None:
    """A person standing still gives the same few points in every frame: too little to calibrate on."""
    positions = np.where(valid[..., None], pixels, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a joint never seen by a view: all-NaN
        spread = np.sqrt(np.sum(np.nanvar(positions, axis=0), axis=-1))  # [C, J] pixels, NaN where never seen
    diagonal = np.linalg.norm(detections.image_size, axis=-1)[:, None]
    motion = float(np.nanmedian(spread / diagonal))
    if not motion > config.min_motion:
        raise CalibrationError(
            f"{detections.source}: the person barely moves (keypoints spread {motion:.2%} of the image diagonal over"
            f" time, median over joints and views; needs > {config.min_motion:.0%}). Calibration needs the"
            " person to move about the scene, e.g. walk through it"
        )


def _initial_rig(pixels: np.ndarray, valid: np.ndarray, K: np.ndarray, detections: RigDetections, config: CalibrationConfig):
    """(R, t, median re-projection error in px of every view's triangulated joints) of the first rig
    through intrinsics K [C, 3, 3] from undistorted pixels [F, C, J, 2]."""
    homogeneous = np.concatenate([pixels, np.ones_like(pixels[..., :1])], -1)
    normalized = np.einsum("cij,fcnj->fcni", np.linalg.inv(K), homogeneous)[..., :2]
    focal = float(np.mean(K[:, [0, 1], [0, 1]]))
    R, t = initial_rig(
        normalized, valid, detections.camera_names, config.ransac_threshold_px / focal, config.min_joints,
        config.min_frames, config.seed,
    )  # fmt: skip
    P = np.concatenate([R, t[..., None]], axis=-1)
    _, projected = triangulate_and_project(P, normalized, valid.astype(np.float32), method="normal")
    projected = np.asarray(projected, np.float64)
    depth = np.where(projected[..., 2:] > 1e-9, projected[..., 2:], np.nan)
    error = np.linalg.norm(projected[..., :2] / depth - normalized, axis=-1) * focal
    return R, t, float(np.nanmedian(np.where(valid, error, np.nan)))


def _initial_rig_and_focal(pixels: np.ndarray, valid: np.ndarray, lens: LensSetup, detections: RigDetections, config: CalibrationConfig):
    """The first rig (R, t) and the lens setup to start the adjustment from.  With unknown focal
    lengths the first rig is made for every candidate of `FOCAL_CANDIDATES` (one focal length for all
    views) and the one whose joints re-project best is kept: a focal length twice off (a wide-angle
    lens under the image-size guess) starts the adjustment in a wrong valley."""
    if not lens.free[:, 0].all():
        R, t, _ = _initial_rig(pixels, valid, lens.K, detections, config)
        return R, t, lens
    best = None
    longer = detections.image_size.max(-1).astype(np.float64)
    for factor in FOCAL_CANDIDATES:
        K = lens.K.copy()
        K[:, [0, 1], [0, 1]] = (factor * longer)[:, None]
        try:
            R, t, error = _initial_rig(pixels, valid, K, detections, config)
        except CalibrationError:
            continue
        if best is None or error < best[2]:
            best = (R, t, error, factor)
    if best is None:  # no candidate gives a rig: the guess's refusal says why
        _initial_rig(pixels, valid, lens.K, detections, config)
    R, t, _, factor = best
    # The adjustment starts at the chosen focal length; the priors stay where they were (theta is
    # relative to the start: the focal prior's mean moves, the principal point's sigma rescales).
    ratio = factor / FOCAL_GUESS_PER_IMAGE_SIDE
    K = lens.K.copy()
    K[:, [0, 1], [0, 1]] *= ratio
    prior_mean, prior_sigma = lens.prior_mean.copy(), lens.prior_sigma.copy()
    prior_mean[:, 0] -= np.log(ratio)
    prior_sigma[:, 1:3] /= ratio
    return R, t, dataclasses.replace(lens, K=K, prior_mean=prior_mean, prior_sigma=prior_sigma)


def calibrate(detections: RigDetections, config: CalibrationConfig = CalibrationConfig()) -> Calibration:
    """Recover the rig of `detections` (see the module docstring); raises `CalibrationError` when the
    detections cannot determine it."""
    start = time.perf_counter()
    valid_all = (detections.confidence >= config.min_confidence) & np.all(np.isfinite(detections.keypoints), -1)
    frames = _select_frames(valid_all, config)
    if len(frames) < config.min_frames:
        raise CalibrationError(
            f"{detections.source}: only {len(frames)} frames in which >= 2 views each see >= {config.min_joints} joints"
            f" (confidence >= {config.min_confidence}); calibration needs >= {config.min_frames}"
        )
    # A joint seen by one view only cannot be triangulated: it would only add noise to the adjustment.
    valid = valid_all[frames] & (valid_all[frames].sum(1, keepdims=True) >= 2)
    estimate_focal = detections.K is None if config.estimate_focal is None else config.estimate_focal
    if not estimate_focal and detections.K is None:
        raise CalibrationError(f"{detections.source}: without K the focal lengths must be estimated (estimate_focal)")
    lens = lens_setup(detections.K, detections.dist, detections.distortion_model, detections.image_size,
                      estimate_focal, config.lens, FOCAL_GUESS_PER_IMAGE_SIDE)  # fmt: skip
    # The first rig sees the detections through the starting lenses (the given ones, or no distortion).
    raw = np.where(valid[..., None], detections.keypoints[frames], 0.0)
    pixels = np.asarray(undistort_compiled(lens.K, lens.dist, raw.astype(np.float32), model=lens.model), np.float64)
    _check_motion(pixels, valid, detections, config)
    R0, t0, lens = _initial_rig_and_focal(pixels, valid, lens, detections, config)
    adjusted = bundle_adjust(R0, t0, lens, raw.astype(np.float64), valid, rounds=config.robust_rounds)
    kept = adjusted.weights > 0.5  # [F, C, J] detections the robust adjustment kept
    reliable = kept.sum(1) >= 2  # [F, J] joints triangulated from two or more of them
    scale = metric_scale(adjusted.points, reliable, detections.skeleton, config.limb_lengths_mm)
    distorted = detections.dist is not None or lens.free[:, 3:].any()
    cameras = Cameras(K=adjusted.K, R=adjusted.R, t=adjusted.t * scale.mm_per_unit, dist=adjusted.dist if distorted else None,
                      distortion_model=lens.model)  # fmt: skip
    return Calibration(
        cameras=cameras,
        camera_names=detections.camera_names,
        image_size=detections.image_size,
        reprojection_median_px=np.nanmedian(adjusted.error_px, axis=(0, 2)),
        reprojection_p90_px=np.nanpercentile(adjusted.error_px, 90, axis=(0, 2)),
        inlier_fraction=kept.sum((0, 2)) / np.maximum(valid.sum((0, 2)), 1),
        scale=scale,
        focal_estimated=estimate_focal,
        lens=adjusted.lens,
        residual_scale=adjusted.residual_scale,
        frames_used=len(frames),
        seconds=time.perf_counter() - start,
    )

