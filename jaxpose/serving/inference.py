"""Single-view inference with a trained lifter: load a run, lift 2D detections to 3D poses.

    from jaxpose.serving import inference
    lifter = inference.load("runs/synthetic")        # the run directory, or its checkpoints/
    poses = lifter.predict(keypoints2d, intrinsics=K, confidence=scores)   # f32[N, J, 3] mm

A run directory (see `jaxpose.training.runner`) holds `checkpoints/`, Orbax steps that each record the
network's skeleton and `ModelConfig` beside its variables (`jaxpose.training.checkpoint`).  Loading needs no
data set, no config file and no training: of the newest readable step (an unreadable one is
reported and the previous one used) only the record and the params and BatchNorm statistics are
read.  The synthetic main job trains on H36M_17; detections in COCO-17 or OpenPose BODY_25 layout
are converted to H36M_17 with `jaxpose.layouts` first.

Inputs, in the conventions of docs/conventions.md: keypoints in pixels of the image the intrinsics
describe; confidence 0 marks a missing joint (its coordinates are ignored, NaN allowed).  The root
(joint 0, the pelvis) must be detected: a pose whose root has confidence 0 cannot be placed
root-relative, and its output row is NaN (the experiments' evaluation skips those views too).
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.training import checkpoint
from jaxpose.training.run_directory import RunDirectory, RunRecord, parse_over_run, read_record
from jaxpose.camera import Cameras, masked_median, normalize_keypoints, undistort_points
from jaxpose.model import ModelConfig
from jaxpose.chunks import map_in_chunks
from jaxpose.data.dataset import window_rows
from jaxpose.flip import flip_averaged
from jaxpose.skeleton import ROOT, Skeleton
from jaxpose.model import make_eval_step

DEFAULT_BATCH_SIZE = 1024

# Keypoints that cannot be right are lifted as missing (confidence 0), for these reasons, in this order
# (a joint is counted under the first that applies): its coordinates are NaN or infinite; its score is
# below a threshold; it lies outside the image by more than a margin.  See `implausible_joints`.
MISSING_REASONS = ("non_finite", "low_confidence", "outside_image")
DEFAULT_MIN_CONFIDENCE = 0.05
"""`jaxpose.predict --min-confidence`: OpenPose's own threshold for drawing a body part (render_threshold
0.05).  Heatmap detectors give an occluded but well-placed joint scores of 0.1-0.3, which should be kept."""
DEFAULT_OUTSIDE_MARGIN = 0.1
"""`jaxpose.predict --outside-margin`: a keypoint more than this fraction of the larger image side outside
the image is missing.  Detectors do place truncated joints a little past the border; a joint hundreds of
pixels away is a detector failure (docs/robust_input.md)."""


T = TypeVar("T")


def parse_with_run(
    args_type: type[T], argv: Sequence[str] | None, description: str, prog: str, run_field: str = "checkpoint"
) -> tuple[T, RunDirectory | None, RunRecord | None]:
    """The command line of a command that lifts with a run (`jaxpose.predict`, `jaxpose.export`) over the run's
    settings (`parse_over_run`): --min-confidence defaults to the threshold the run was trained with (its
    run.json; `DEFAULT_MIN_CONFIDENCE` for a run without one); one given that differs from the run's is said in
    one line.  Returns the arguments, the run's folder and its record, for `load`."""

    def trained(record: RunRecord | None) -> float | None:
        return None if record is None else record.min_confidence

    def defaults(record: RunRecord | None) -> dict[str, float]:
        return {"min_confidence": DEFAULT_MIN_CONFIDENCE if trained(record) is None else trained(record)}

    args, run, record = parse_over_run(args_type, argv, defaults, description, prog, run_field)
    if trained(record) is not None and args.min_confidence != trained(record):
        print(f"--min-confidence {args.min_confidence:g} given; the run was trained with {trained(record):g} ({run.record})", file=sys.stderr)
    return args, run, record


def implausible_joints(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    image_size: Sequence[float] | None = None,
    outside_margin: float | None = DEFAULT_OUTSIDE_MARGIN,
    min_confidence: float = 0.0,
) -> dict[str, np.ndarray]:
    """bool[N, J] per reason of `MISSING_REASONS`: the given joints (confidence > 0) that cannot be right.

    "non_finite": a NaN or infinite coordinate with a positive score, or a NaN or infinite score;
    "low_confidence": 0 < confidence < `min_confidence`;
    "outside_image": more than `outside_margin` x max(width, height) outside [0, width] x [0, height]
    (only where `image_size` is known and `outside_margin` is not None).  Each joint is counted under
    the first reason that applies, so the masks are disjoint.
    """
    keypoints = np.asarray(keypoints, np.float32)
    confidence = np.asarray(confidence, np.float32)
    if confidence.shape != keypoints.shape[:-1]:
        raise ValueError(f"confidence: expected shape {keypoints.shape[:-1]} (one score per keypoint), got {confidence.shape}")
    bad_score = ~np.isfinite(confidence)
    given = (confidence > 0) | bad_score
    with np.errstate(invalid="ignore"):
        non_finite = given & (~np.isfinite(keypoints).all(-1) | bad_score)
        low = given & ~non_finite & (confidence < min_confidence)
        outside = np.zeros_like(given)
        if image_size is not None and outside_margin is not None:
            width, height = (float(v) for v in image_size)
            margin = outside_margin * max(width, height)
            x, y = keypoints[..., 0], keypoints[..., 1]
            beyond = (x < -margin) | (x > width + margin) | (y < -margin) | (y > height + margin)
            outside = given & ~non_finite & ~low & beyond
    return {"non_finite": non_finite, "low_confidence": low, "outside_image": outside}


DEFAULT_INCONSISTENT_RESIDUAL = 2.0
"""The measured choice for `jaxpose.predict --reject-inconsistent` (off by default): how far, in median
joint-to-root distances of the pose, a joint may lie from where the rest of the pose puts it (see
`leave_one_out_residuals`).  With a Human3.6M development lifter trained with `--train.augment.drop 0.1`,
a joint moved 200 px changes the others by 37.8 mm at the median instead of 106.9, and 0.4% of the clean
SH test poses lose a joint (P-MPJPE +0.1 mm); with one trained without dropping, 1.0% (+0.6 mm), which
is why it is not on by default (docs/robust_input.md)."""


MIN_JOINTS_FOR_RESIDUAL = 3


@functools.partial(jax.jit, static_argnums=0)
def leave_one_out_residuals(eval_step: Callable[..., jax.Array], variables, keypoints, K, confidence) -> jax.Array:
    """How badly each joint fits the rest of its pose: f32[N, J] for undistorted keypoints [N, J, 2] px.

    Joint j is lifted as missing and the lifted pose's (x, y) is compared with the detected pose, both
    root-relative and divided by their median joint-to-root distance over the other given joints (the
    camera-frame (x, y) of a root-relative pose is its image up to scale, under weak perspective).  The
    residual is how far detected joint j lies from where the rest of the pose puts it, in those units.
    A wild joint left out is far from its prediction; a good joint left out is predicted near where it
    is, if the lifter fills in missing joints well, as one trained with `--train.augment.drop` does
    (docs/robust_input.md).  Medians, not a least-squares fit, so that a far joint cannot set the scale
    of every other joint's residual.  0 for the root, for missing joints, for every joint of a pose
    whose root is missing, and where fewer than `MIN_JOINTS_FOR_RESIDUAL` other joints are given (their
    median says nothing of the pose's size).
    """
    N, J = confidence.shape
    given = (confidence > 0) & (jnp.arange(J) != 0) & (confidence[:, :1] > 0)
    others = given[:, None, :] & ~jnp.eye(J, dtype=bool)[1:]  # [N, J-1, J]: the joints given, but the left-out one

    def in_median_units(points):  # [N, J-1, J, 2] root-relative -> divided by the median distance of `others`
        scale = masked_median(jnp.linalg.norm(points, axis=-1), others)
        return points / jnp.maximum(scale, 1e-12)[..., None, None]

    relative = normalize_keypoints(keypoints, K, confidence, "intrinsics")
    lifted = eval_step(
        variables,
        jnp.broadcast_to(keypoints[:, None], (N, J - 1, J, 2)).reshape(-1, J, 2),
        jnp.broadcast_to(K[:, None], (N, J - 1, 3, 3)).reshape(-1, 3, 3),
        jnp.where(jnp.eye(J, dtype=bool)[1:], 0.0, confidence[:, None, :]).reshape(-1, J),
    ).reshape(N, J - 1, J, 3)[..., :2]
    left_out = jnp.arange(1, J)
    detected = in_median_units(jnp.broadcast_to(relative[:, None], lifted.shape))[:, left_out - 1, left_out]
    predicted = in_median_units(lifted)[:, left_out - 1, left_out]
    residual = jnp.linalg.norm(detected - predicted, axis=-1)  # [N, J-1]
    measurable = given[:, 1:] & (others.sum(-1) >= MIN_JOINTS_FOR_RESIDUAL)
    return jnp.concatenate([jnp.zeros((N, 1), residual.dtype), jnp.where(measurable, residual, 0.0)], axis=1)


def default_intrinsics(image_size: Sequence[float]) -> np.ndarray:
    """The intrinsics assumed for an uncalibrated camera: f32[3, 3] for image_size (width, height) px.

    Focal length max(width, height) in both axes (about 53 degrees of horizontal field of view for a
    landscape image, the usual guess of in-the-wild pipelines), principal point at the image centre,
    no skew, no distortion.  The lifter's input is root-relative, so the principal point cancels; with
    `input_normalization` "intrinsics_scale" or "intrinsics_median" the pose is also scaled to unit size, so the
    focal length cancels too and only fx/fy matters: the guess is then harmless.
    """
    size = np.asarray(image_size, np.float64)
    if size.shape != (2,) or not np.isfinite(size).all() or (size <= 0).any():
        raise ValueError(f"image_size: expected (width, height) in pixels, both positive, got {image_size!r}")
    focal = size.max()
    return np.array([[focal, 0.0, size[0] / 2], [0.0, focal, size[1] / 2], [0.0, 0.0, 1.0]], np.float32)


@jax.jit
def _undistort(K: jax.Array, dist: jax.Array, keypoints: jax.Array) -> jax.Array:
    """OpenCV-model undistortion of [N, J, 2] pixels with per-pose K [N, 3, 3] and dist [N, 5]."""
    cameras = Cameras(K=K, R=jnp.broadcast_to(jnp.eye(3), K.shape), t=jnp.zeros(K.shape[:-1]), dist=dist)
    return undistort_points(cameras, keypoints)


def _chunk_size(count: int, batch_size: int) -> int:
    """Rows per predictor call: the next power of two >= count, at most batch_size.

    Each chunk size compiles once, so any sequence of calls compiles at most log2(batch_size) + 1
    times, and a single pose does not pay for a full batch.
    """
    return min(batch_size, 1 << max(count - 1, 0).bit_length())


@dataclasses.dataclass(frozen=True)
class LifterInput:
    """N single-view poses as the lifter reads them, prepared once (`Lifter3D.prepare`) and used alike by
    the lift (`Lifter3D.lift`) and the inconsistency check (`Lifter3D.inconsistent_joints`)."""

    keypoints: np.ndarray
    """f32[N, J, 2] undistorted pixels, 0 where missing."""
    K: np.ndarray
    """f32[N, 3, 3] each pose's intrinsics."""
    confidence: np.ndarray
    """f32[N, J] the detector's scores, 0 where missing (not detected, below the score threshold, outside
    the image, or beyond what the lens model undistorts)."""

    def without(self, joints: np.ndarray) -> LifterInput:
        """The same poses with `joints` (bool[N, J]) missing."""
        return LifterInput(
            np.where(joints[..., None], 0.0, self.keypoints).astype(np.float32), self.K, np.where(joints, 0.0, self.confidence).astype(np.float32)
        )


@dataclasses.dataclass(frozen=True)
class Lifter3D:
    """A trained lifter, ready to lift single-view 2D poses; build it with `load`."""

    skeleton: Skeleton
    """The joint layout the checkpoint lifts (input and output)."""
    model_config: ModelConfig
    variables: dict[str, Any] = dataclasses.field(repr=False)
    """{"params": ..., "batch_stats": ...} of the restored step."""
    step: int
    """The training step of the restored checkpoint."""
    source: pathlib.Path
    """The checkpoints directory it was restored from."""
    eval_step: Callable[..., jax.Array] = dataclasses.field(repr=False)
    batch_size: int = DEFAULT_BATCH_SIZE
    """The most poses per jitted call."""
    record: RunRecord | None = None
    """What its run was trained on (run.json: the score threshold, the layout, a rig project's settings),
    for the commands that apply it; None for a run from before the record."""

    @functools.cached_property
    def flipped_eval_step(self) -> Callable[..., jax.Array]:
        """`eval_step` averaged with the lift of the mirror image (`jaxpose.flip.flip_averaged`)."""
        return flip_averaged(self.eval_step, self.skeleton)

    @property
    def num_joints(self) -> int:
        return self.skeleton.num_joints

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.skeleton.joint_names

    def predict(
        self,
        keypoints2d,
        intrinsics=None,
        confidence=None,
        distortion=None,
        image_size: Sequence[float] | None = None,
        min_confidence: float = 0.0,
        outside_margin: float | None = None,
        reject_inconsistent: float | None = None,
        flip: bool = False,
    ) -> np.ndarray:
        """Root-relative 3D poses f32[N, J, 3] in mm, in each camera's frame (x right, y down, z forward).

        keypoints2d: [N, J, 2] pixels (or one pose [J, 2], giving [J, 3]), in `self.skeleton`'s order.
                     For a temporal lifter (`temporal_window` > 1) the N poses are ONE person's sequence,
                     frame after frame, and each is lifted with the window of frames around it (the
                     sequence's first and last frames repeated beyond its ends); a frame without a pose
                     is given with confidence 0.
        intrinsics:  K [3, 3] shared by all poses, or [N, 3, 3] one per pose; None = `default_intrinsics(image_size)`.
        confidence:  [N, J] detector scores; only > 0 (detected) vs 0 (missing) matters.  None = all detected.
        distortion:  OpenCV (k1, k2, p1, p2, k3), [5] or [N, 5]: the keypoints are undistorted first.
                     None = the keypoints are undistorted (pinhole) pixels already.
        min_confidence: joints scored below this are lifted as missing (default 0: every score > 0 counts).
        outside_margin: with `image_size`, joints more than this fraction of the larger image side
                     outside the image are lifted as missing (`implausible_joints`; None = no check).
        reject_inconsistent: a residual (e.g. `DEFAULT_INCONSISTENT_RESIDUAL`): in each pose, the joint that
                     fits the rest of the pose worst is lifted as missing if its residual is larger
                     (`inconsistent_joints`; None = no check).  Frame lifters only.
        flip:        test-time flip augmentation (`jaxpose.flip`): each pose and its mirror image are lifted
                     and averaged, at twice the cost.  The rejection's test still uses the plain lift.
        Rows whose root (joint 0) is missing are NaN.  Non-finite keypoints with confidence > 0 are an
        error here (`jaxpose.predict` reports them and lifts them as missing).
        """
        inputs = self.prepare(keypoints2d, intrinsics, confidence, distortion, image_size, min_confidence, outside_margin)
        if reject_inconsistent is not None:
            inputs = inputs.without(self.inconsistent_joints(inputs, reject_inconsistent))
        poses = self.lift(inputs, flip)
        return poses[0] if np.ndim(keypoints2d) == 2 else poses

    def lift(self, inputs: LifterInput, flip: bool = False) -> np.ndarray:
        """Root-relative 3D poses f32[N, J, 3] in mm of prepared poses (`prepare`), NaN where the root is
        missing; `flip` as `predict`'s."""
        keypoints, K, confidence = inputs.keypoints, inputs.K, inputs.confidence
        count = len(keypoints)
        poses = np.full((count, self.num_joints, 3), np.nan, np.float32)
        liftable = np.flatnonzero(confidence[:, ROOT] > 0)
        if len(liftable):
            lift = functools.partial(self.flipped_eval_step if flip else self.eval_step, self.variables)
            window = self.model_config.temporal_window
            if window > 1:  # [N, T, J, 2]: each frame's window in the sequence
                frames = window_rows(liftable, np.array([[0, count]]).repeat(len(liftable), 0), window)
                batch = (keypoints[frames], K[liftable], confidence[frames])
            else:
                batch = (keypoints[liftable], K[liftable], confidence[liftable])
            poses[liftable] = map_in_chunks(lift, batch, _chunk_size(len(liftable), self.batch_size))
        return poses

    def inconsistent_joints(self, inputs: LifterInput, threshold: float = DEFAULT_INCONSISTENT_RESIDUAL) -> np.ndarray:
        """bool[N, J]: per prepared pose (`prepare`), the joint `predict(..., reject_inconsistent=threshold)`
        lifts as missing (at most one: the largest `leave_one_out_residuals`, where it exceeds `threshold`);
        the joints missing already are not counted.  Frame lifters only."""
        if self.model_config.temporal_window > 1:
            raise ValueError("rejecting inconsistent joints needs a frame lifter; this one reads windows of frames")
        if not threshold > 0:
            raise ValueError(f"reject_inconsistent (the residual threshold) must be > 0, got {threshold}")
        keypoints, K, confidence = inputs.keypoints, inputs.K, inputs.confidence
        rows = np.flatnonzero(confidence[:, ROOT] > 0)
        rejected = np.zeros(confidence.shape, bool)
        if len(rows):
            residual = map_in_chunks(
                functools.partial(leave_one_out_residuals, self.eval_step, self.variables),
                (keypoints[rows], K[rows], confidence[rows]),
                _chunk_size(len(rows), max(1, self.batch_size // self.num_joints)),
            )
            worst = residual.argmax(-1)
            flagged = residual[np.arange(len(rows)), worst] > threshold
            rejected[rows[flagged], worst[flagged]] = True
        return rejected

    def prepare(
        self,
        keypoints2d,
        intrinsics=None,
        confidence=None,
        distortion=None,
        image_size: Sequence[float] | None = None,
        min_confidence: float = 0.0,
        outside_margin: float | None = None,
    ) -> LifterInput:
        """The lifter's input of poses given as `predict`'s arguments (one pose [J, 2] becomes N = 1): checked,
        undistorted, the joints below `min_confidence` or outside the image by `outside_margin` missing."""
        keypoints = np.asarray(keypoints2d, np.float32)
        if keypoints.ndim == 2:
            keypoints = keypoints[None]
            confidence = None if confidence is None else np.asarray(confidence)[None]
        keypoints, confidence = self._check_keypoints(keypoints, confidence)
        if min_confidence > 0 or (outside_margin is not None and image_size is not None):
            dropped = implausible_joints(keypoints, confidence, image_size, outside_margin, min_confidence)
            keep = ~(dropped["low_confidence"] | dropped["outside_image"])
            confidence = np.where(keep, confidence, 0.0).astype(np.float32)
            keypoints = np.where(keep[..., None], keypoints, 0.0).astype(np.float32)
        count = len(keypoints)
        K = _check_intrinsics(intrinsics, image_size, count)
        if distortion is not None:
            if intrinsics is None:
                raise ValueError("distortion needs the calibrated intrinsics it belongs to; pass intrinsics= too")
            dist = _check_per_pose("distortion", distortion, (5,), count)
            keypoints = np.asarray(_undistort(K, dist, keypoints))
            # Missing joints were zeroed, and undistorting (0, 0) may diverge: keep them at zero; a joint the lens
            # model cannot undistort (far outside the image: NaN, `camera.UNDISTORTION_TOLERANCE`) is missing too.
            confidence = np.where(np.isfinite(keypoints).all(-1), confidence, 0.0).astype(np.float32)
            keypoints = np.where(confidence[..., None] > 0, keypoints, 0.0).astype(np.float32)
        return LifterInput(keypoints, K, confidence)

    def _check_keypoints(self, keypoints: np.ndarray, confidence) -> tuple[np.ndarray, np.ndarray]:
        """Shapes and values of keypoints/confidence; returns them with missing joints zeroed."""
        if keypoints.ndim != 3 or keypoints.shape[-1] != 2:
            raise ValueError(f"keypoints2d: expected [N, J, 2] or [J, 2] pixels, got shape {keypoints.shape}")
        if keypoints.shape[1] != self.num_joints:
            raise ValueError(
                f"keypoints2d has {keypoints.shape[1]} joints per pose, but the checkpoint in {self.source} lifts"
                f" skeleton {self.skeleton.name!r} with J={self.num_joints} joints {self.joint_names}; convert"
                " detector layouts with jaxpose.layouts (COCO-17 and OpenPose BODY_25 -> h36m17)"
            )
        if confidence is None:
            confidence = np.ones(keypoints.shape[:2], np.float32)
        confidence = np.asarray(confidence, np.float32)
        if confidence.shape != keypoints.shape[:2]:
            raise ValueError(f"confidence: expected shape {keypoints.shape[:2]} (N, J), got {confidence.shape}")
        bad = ~np.isfinite(confidence) | (confidence < 0)
        if bad.any():
            pose, joint = np.argwhere(bad)[0]
            value = confidence[pose, joint]
            raise ValueError(f"confidence must be finite and >= 0; pose {pose} joint {joint} has {value}")
        bad = ~np.isfinite(keypoints).all(-1) & (confidence > 0)
        if bad.any():
            pose, joint = np.argwhere(bad)[0]
            raise ValueError(
                f"keypoints2d: {int(bad.sum())} non-finite keypoints with confidence > 0, first pose {pose} joint"
                f" {joint} ({self.joint_names[joint]}) = {keypoints[pose, joint]}; give missing joints confidence 0"
            )
        return np.where(confidence[..., None] > 0, keypoints, 0.0).astype(np.float32), confidence


def _check_per_pose(name: str, values, shape: tuple[int, ...], count: int) -> np.ndarray:
    """`values` of `shape` (shared) or (count, *shape) (one per pose), finite, as f32[count, *shape]."""
    array = np.asarray(values, np.float32)
    if array.shape == shape:
        array = np.broadcast_to(array, (count, *shape))
    elif array.shape != (count, *shape):
        raise ValueError(f"{name}: expected shape {shape} or {(count, *shape)} for {count} poses, got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return np.ascontiguousarray(array)


def _check_intrinsics(intrinsics, image_size, count: int) -> np.ndarray:
    """f32[count, 3, 3] intrinsics from K, per-pose K, or the default of an image size."""
    if intrinsics is None:
        if image_size is None:
            raise ValueError(
                "no intrinsics: pass intrinsics= (K [3, 3] or [N, 3, 3]) or image_size=(width, height) for the"
                " default camera (focal length max(width, height), principal point at the image centre)"
            )
        intrinsics = default_intrinsics(image_size)
    K = _check_per_pose("intrinsics", intrinsics, (3, 3), count)
    if (K[:, 0, 0] <= 0).any() or (K[:, 1, 1] <= 0).any():
        raise ValueError("intrinsics: focal lengths K[0, 0] and K[1, 1] must be positive")
    upper_triangular = np.isclose(K[:, 2], [0.0, 0.0, 1.0]).all(-1) & np.isclose(K[:, 1, 0], 0.0)
    if not upper_triangular.all():
        bad = np.flatnonzero(~upper_triangular)[0]
        raise ValueError(
            f"intrinsics: expected K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (is it transposed?), got {K[bad].tolist()}"
        )
    return K


def load(path: str | pathlib.Path | RunDirectory, batch_size: int = DEFAULT_BATCH_SIZE) -> Lifter3D:
    """The lifter of a run: `path` is the run directory or its checkpoints/ directory (or the `RunDirectory`
    a command built for it, `parse_with_run`).

    Restores the newest readable checkpoint (on the default device), with the run's record (`Lifter3D.record`).  Raises FileNotFoundError for a
    missing run directory or checkpoints/, and `jaxpose.training.checkpoint.CheckpointError` when no step
    can be read.
    """
    run = path if isinstance(path, RunDirectory) else RunDirectory.of(path)
    path = path.path if isinstance(path, RunDirectory) else path
    if not run.checkpoints.is_dir():
        raise FileNotFoundError(
            f"{path} does not exist; expected a run directory (with checkpoints/) or its checkpoints/" if not pathlib.Path(path).exists()
            else f"{path} has no checkpoints/ directory: expected a run directory written by the experiments, or its checkpoints/"
            " directory (a run saves its first checkpoint after `train.checkpoint-every` steps)"
        )
    checkpoints = run.checkpoints
    restored = checkpoint.restore_lifter(checkpoints, jax.sharding.SingleDeviceSharding(jax.devices()[0]))
    if restored is None:
        raise checkpoint.CheckpointError(f"{checkpoints} holds no checkpoint (the run saves its first one later)")
    step, network, variables = restored
    model = network.model.build(network.skeleton.num_joints)
    return Lifter3D(
        skeleton=network.skeleton,
        model_config=network.model,
        variables=variables,
        step=step,
        source=checkpoints,
        eval_step=make_eval_step(model, network.model),
        batch_size=batch_size,
        record=read_record(run),
    )
