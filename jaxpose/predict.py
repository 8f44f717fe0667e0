"""Lift 2D detections from a file to 3D poses with a trained run (single-view inference).

    python -m jaxpose.predict --checkpoint runs/synthetic --input detections.json --output poses.json \\
        --image-size 1920 1080 --plot plots/

Inputs (the kind is told by the path; read by `jaxpose.formats.detection_file`):
- COCO keypoint results, a ``.json`` list of {"image_id", "category_id", "keypoints": [x, y, score] * 17,
  "score"} (what COCO-style detectors write; AlphaPose's file-name image ids and extra keys too); one pose
  per entry, in file order.
- OpenPose output, a folder of per-frame ``.json`` files (``--write_json``; also Pose2Sim's
  ``cam01.0010.json`` and ``frame_00001.json``), in frame-number order (the last digits of the name):
  every person's ``pose_keypoints_2d`` is one pose, its image id the file name without
  ``_keypoints.json`` (or ``.json``).  A single such file works too.
  The layout of both is told by the values per person: 51 COCO-17, 54 COCO-18, 78 HALPE_26.  75 are
  BODY_25 or BODY_25B, which the count cannot tell apart: a BODY_25 or BODY_25B lifter reads them in
  its own layout, any other lifter needs --format body25 or --format body25b.
- ``.npz`` with ``keypoints`` [N, J, 2] px and optionally ``confidence`` [N, J], ``image_id`` [N] and
  ``K`` [N, 3, 3] (one camera per pose); the keypoints are in the checkpoint's own joint layout unless
  --format names one to convert from.
The keypoints are converted to the checkpoint's joints by `jaxpose.layouts.to_skeleton`: a lifter
trained on a rig project (`experiments.rig`) takes its detector's own layout, and the H36M_17 lifters of
the benchmarks take COCO-17, BODY_25 and HALPE_26 (through its COCO-17 keypoints).

Output by suffix (see --output; `jaxpose.formats.pose_files`), root-relative, on the input's time axis: each
pose keeps its frame (an OpenPose file's index, a COCO image id's number), its time (frame - first frame) / --fps
and its person, followed through the frames by its 2D keypoints (`jaxpose.serving.tracking`).  A ``.trc`` is a file per
person, a row per frame: gaps of up to --max-gap frames are interpolated, a longer one starts a new file, and
the command prints what it filled and split.

Keypoints that cannot be right are lifted as missing, and the command says how many joints of how many
poses it treated so, per reason (`jaxpose.serving.inference.implausible_joints`): NaN or infinite coordinates
with a positive score, a score below --min-confidence (default: the threshold the run was trained with, else 0.05), and, where the image size is known
(--image-size, or the --intrinsics calibration's), a keypoint more than --outside-margin (default 10%) of
the larger image side outside the image.  Then, in each pose, the joint that fits the rest of the pose
worst can be lifted as missing where it lies more than --reject-inconsistent (2 for a lifter trained with
--train.augment.drop 0.1; off by default) median joint-to-root distances from where the rest of the pose
puts it (frame lifters; `jaxpose.serving.inference.inconsistent_joints`), and the command says how many.  One
wild keypoint would otherwise move the whole lifted pose (docs/robust_input.md).

--flip lifts each pose and its mirror image and averages the two (test-time flip augmentation, `jaxpose.flip`).

A pose whose root (the pelvis; for COCO/OpenPose both hips) was not detected cannot be lifted: it is null,
NaN or empty in the output.

``--animation clip.gif`` (or ``.mp4``) animates a sequence, one frame per image id: the 2D input beside
the lifted 3D pose.

No file is written over without --overwrite, nor an input ever, all checked before anything is read; each is
written to a temporary name renamed into place when complete (`jaxpose.formats.outputs`).
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys
from collections.abc import Sequence
from typing import Annotated, Literal

import numpy as np
import tyro
from tqdm.auto import tqdm

from jaxpose import viz

from jaxpose.serving import inference, lifting_figures, tracking
from jaxpose.training.checkpoint import CheckpointError
from jaxpose.training.run_directory import RunDirectory
from jaxpose.compilation_cache import enable_compilation_cache
from jaxpose.formats import detection_file, gaps, intrinsics, pose_files
from jaxpose.formats.outputs import OutputError, check_output, check_output_folder
from jaxpose.layouts import LAYOUTS, check_body25_layout, infer_layout, layout_joint_names, layout_of, to_skeleton
from jaxpose.logs import show_logs

# Poses per `Lifter3D.predict` call; inputs larger than this get a progress bar.
LIFT_BLOCK = 16384


@dataclasses.dataclass(frozen=True)
class PredictArgs:
    """The command's flags."""

    checkpoint: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory or its checkpoints/ folder; the newest readable step is used."""
    input: Annotated[pathlib.Path, tyro.conf.arg(metavar="FILE")]
    """COCO keypoint-results .json, OpenPose folder of per-frame .json files (or one such file), or .npz
    (keypoints, confidence, image_id, K)."""
    output: Annotated[pathlib.Path, tyro.conf.arg(metavar="FILE")]
    """Output by suffix, root-relative: a pose per input pose as .json (list of {image_id, frame, time_s,
    person, pose3d_mm, joint_names}), .npz (pose3d_mm, valid, image_id, frame, time_s, person, joint_names)
    or .csv (image_id, frame, time_s, person, <joint>_x_mm, ...; empty cells where a pose could not be
    lifted), in mm in the camera frame (x right, y down, z forward); or .trc, OpenSim markers in m (axes
    X = -z, Y = -y, Z = -x of the camera: X forward, Y up, Z right for a subject facing the camera), a row per
    frame, Frame# the input's frame, Time = (frame - first frame) / --fps: FILE itself where one person is
    followed without a gap over --max-gap, else <stem>.person<P>.trc and <stem>.person<P>.seg<S>.trc."""
    format: Literal[LAYOUTS] | None = None  # type: ignore[valid-type]
    """Joint layout of the input keypoints (default: the checkpoint's own detector layout where it was
    trained on one and the file's keypoint count fits it; else told by the keypoint count for COCO and
    OpenPose .json, 75 values (BODY_25 or BODY_25B) refused; the checkpoint's own joints for .npz)."""
    intrinsics: Annotated[tuple[str, ...] | None, tyro.conf.arg(metavar="VALUE [VALUE ...]")] = None
    """Camera intrinsics in pixels: four values fx fy cx cy; a rig calibration file and a camera name (e.g.
    calibration.toml cam01: Anipose / Pose2Sim / FreeMoCap TOML, EasyMocap intri.yml, jaxpose camera file);
    or one JSON camera file {K, dist, image_size}.  An OpenCV distortion (k1 k2 p1 p2 k3) is undone before
    lifting.  Default: focal length max(W, H) and the image centre of --image-size."""
    image_size: Annotated[tuple[float, float] | None, tyro.conf.arg(metavar="W H")] = None
    """Image width and height in pixels: the default intrinsics, and the frame of the plots."""
    plot: Annotated[pathlib.Path | None, tyro.conf.arg(metavar="DIR")] = None
    """Save 2D-detection / 3D-pose figures (PNG) of the first lifted poses into DIR."""
    plot_count: int = 4
    """Poses --plot draws."""
    animation: Annotated[pathlib.Path | None, tyro.conf.arg(metavar="FILE")] = None
    """Write an animation of the sequence, .gif or .mp4 by suffix (.mp4 needs ffmpeg: on PATH, or pip install
    'jaxpose[video]'): a frame per image id (numbers in numerical order, names as they sort; OpenPose frames
    in frame-number order, empty ones too), the 2D input beside the lifted 3D pose, at limits fixed over the sequence.
    A frame with several people shows the pose with the highest mean keypoint score, lifted ones first."""
    fps: float = 10.0
    """Frames per second of the input sequence (pass your video's; the default is 10): the outputs' time,
    (frame - first frame) / fps in seconds, a .trc's DataRate, and the rate of --animation."""
    max_gap: int = gaps.DEFAULT_MAX_GAP
    """A .trc output: up to this many frames in a row without a lifted pose of a person are filled by linear
    interpolation (Pose2Sim's default, 10); a longer gap ends the file and a new segment begins."""
    track_gap: int = tracking.DEFAULT_TRACK_GAP
    """Frames a person may go unseen and still be followed (`jaxpose.serving.tracking`); one who comes back later
    counts as another person."""
    overwrite: bool = False
    """Replace existing output files (--output, a .trc output's person files, --animation, the --plot
    figures); without it the command stops before any work.  A file the command reads is never replaced."""
    batch_size: int = inference.DEFAULT_BATCH_SIZE
    """Most poses per jitted lifter call."""
    min_confidence: float = inference.DEFAULT_MIN_CONFIDENCE
    """Keypoints scored below this are lifted as missing (0 keeps every keypoint with a positive score).
    Default: the threshold the run was trained with (its run.json; a rig project's --data.min-confidence),
    else 0.05; `--help` with --checkpoint shows it."""
    outside_margin: float | None = inference.DEFAULT_OUTSIDE_MARGIN
    """Keypoints more than this fraction of the larger image side outside the image are lifted as missing
    (needs the image size: --image-size or a calibration that has it); None disables the check."""
    reject_inconsistent: float | None = None
    """In each pose, the joint that fits the rest of the pose worst is lifted as missing where it lies farther
    than this many median joint-to-root distances from where the rest of the pose puts it (frame lifters;
    `jaxpose.serving.inference.leave_one_out_residuals`).  2 is the measured choice for a lifter trained with
    --train.augment.drop 0.1; off by default, as it costs a lifter trained without it accuracy
    (docs/robust_input.md)."""
    flip: bool = False
    """Test-time flip augmentation (`jaxpose.flip`): each pose and its mirror image (x -> -x in normalised
    camera coordinates, left and right swapped) are lifted and the two poses averaged, at twice the lifting
    time (docs/lifting.md, "Test-time flip")."""


def run(args: PredictArgs, run_dir: RunDirectory) -> np.ndarray:
    """The whole command: read, convert, lift, write, plot, animate, with the lifter of `run_dir` (--checkpoint's
    run, as the command line read it).  Returns the poses f32[N, J, 3]."""
    check_args(args)
    earlier = check_outputs(args)
    detections = detection_file.read_detections(args.input)
    if detections.frames_note:
        print(detections.frames_note, file=sys.stderr)
    if detections.clipped_scores:
        print(f"{detections.clipped_scores} scores above 1 clipped to 1 (docs/files.md)", file=sys.stderr)
    lifter = inference.load(run_dir, batch_size=args.batch_size)
    camera = input_camera(args, detections)
    layout = args.format or input_layout(lifter.skeleton, detections)
    scores = detections.scores if detections.scores is not None else np.ones(detections.keypoints.shape[:2], np.float32)
    if layout is not None:
        check_body25_layout(layout, detections.keypoints, scores, str(args.input), "--format")
    names = input_joint_names(layout, lifter.joint_names, detections.keypoints.shape[1])
    scores, message = drop_implausible(
        detections.keypoints, scores, names, camera.image_size, args.min_confidence, args.outside_margin
    )
    print(message, file=sys.stderr)
    if layout is None:
        keypoints, confidence = detections.keypoints, scores
    else:
        keypoints, confidence = to_skeleton(layout, lifter.skeleton, detections.keypoints, scores)
    persons = tracking.follow_people(detections.frames, keypoints, confidence > 0, max_gap=args.track_gap)
    count = len(keypoints)
    not_followed = 0  # a temporal lifter's other people in a frame
    if lifter.model_config.temporal_window > 1:
        if args.reject_inconsistent is not None:
            print("--reject-inconsistent: frame lifters only, not applied to this temporal lifter", file=sys.stderr)
        poses, not_followed = lift_sequence(lifter, keypoints, confidence, camera, detections, args.flip)
    else:
        poses, rejected = lift_frames(lifter, keypoints, confidence, camera, args.reject_inconsistent, args.flip)
        if args.reject_inconsistent is not None:
            print(rejection_report(rejected, keypoints, lifter.joint_names, args.reject_inconsistent), file=sys.stderr)
            confidence = np.where(rejected, 0.0, confidence).astype(np.float32)  # the plots show them as missing
    lifted_poses = pose_files.LiftedPoses(
        poses, lifter.joint_names, detections.image_ids, detections.frames, persons, detections.first_frame, args.fps
    )
    if args.output.suffix == ".trc":
        written = pose_files.write_trc_files(args.output, lifted_poses, args.max_gap)
        print(pose_files.trc_summary(written, lifted_poses, args.max_gap, earlier), file=sys.stderr)
    else:
        pose_files.write_poses(args.output, lifted_poses)
    lifted = int(np.isfinite(poses).all((1, 2)).sum())
    rootless = count - lifted - not_followed
    unliftable = f"; {rootless} without a detected root are null" if rootless else ""
    unliftable += f"; {not_followed} other people, not followed, are null" if not_followed else ""
    print(
        f"lifted {lifted} of {count} poses with the {lifter.skeleton.name} lifter (step {lifter.step}"
        f"{', test-time flip' if args.flip else ''}) of"
        f" {lifter.source} -> {'the .trc files above' if args.output.suffix == '.trc' else args.output}{unliftable}",
        file=sys.stderr,
    )
    result = lifting_figures.LiftedInput(keypoints, confidence, poses, detections.image_ids, detections.frame_ids)
    if args.plot is not None:
        saved = lifting_figures.save_plots(args.plot, result, lifter.skeleton, camera.image_size, args.plot_count)
        print(f"saved {len(saved)} figures to {args.plot}", file=sys.stderr)
    if args.animation is not None:
        lifting_figures.save_animation(args.animation, result, lifter.skeleton, camera.image_size, args.fps)
        print(f"saved the animation {args.animation}", file=sys.stderr)
    return poses


def check_args(args: PredictArgs) -> None:
    """The flags' own errors, before anything is read."""
    if args.output.suffix not in pose_files.SUFFIXES:
        raise ValueError(f"--output {args.output}: the suffix must be one of {pose_files.SUFFIXES}")
    if not 0 < args.fps < float("inf"):
        raise ValueError(f"--fps must be a positive finite number, got {args.fps}")
    if args.max_gap < 0 or args.track_gap < 0:
        raise ValueError(f"--max-gap and --track-gap must be >= 0, got {args.max_gap} and {args.track_gap}")
    if args.animation is not None:
        try:  # a wrong suffix, or no encoder for .mp4, fails before the lifting
            viz.check_animation_path(args.animation, args.fps)
        except ValueError as error:
            raise ValueError(f"--animation {error}") from None
    if not 0.0 <= args.min_confidence <= 1.0:
        raise ValueError(f"--min-confidence must lie in [0, 1], got {args.min_confidence}")
    if args.outside_margin is not None and not args.outside_margin >= 0:
        raise ValueError(f"--outside-margin must be >= 0, got {args.outside_margin}")
    if args.reject_inconsistent is not None and not args.reject_inconsistent > 0:
        raise ValueError(f"--reject-inconsistent must be > 0, got {args.reject_inconsistent}")


def check_outputs(args: PredictArgs) -> list[pathlib.Path]:
    """Refuse, before any work, an output that exists (without --overwrite), that is a folder (a file for
    --plot) or that is one of the command's inputs (`jaxpose.formats.outputs.check_output`).  A .trc output
    may write person files beside FILE: returns those that exist (`pose_files.trc_family`), each checked."""
    inputs = [args.input, args.checkpoint, *(value for value in args.intrinsics or () if pathlib.Path(value).is_file())]
    check_output(args.output, args.overwrite, inputs)
    earlier = pose_files.trc_family(args.output) if args.output.suffix == ".trc" else []
    for path in earlier:
        check_output(path, args.overwrite, inputs)
    if args.animation is not None:
        check_output(args.animation, args.overwrite, [*inputs, args.output], flag="--animation")
    if args.plot is not None:
        check_output_folder(args.plot, inputs, flag="--plot")
        for other, flag in ((args.output, "--output"), (args.animation, "--animation")):
            if other is not None and args.plot.resolve() == other.resolve():
                raise OutputError(f"--plot {args.plot}: is also the {flag} file; give the figures a folder of their own")
        figures = sorted(args.plot.glob(lifting_figures.PLOT_PATTERN)) if args.plot.is_dir() else []
        if figures and not args.overwrite:
            raise OutputError(
                f"--plot {args.plot}: holds {len(figures)} figures {lifting_figures.PLOT_PATTERN} already ({figures[0].name}, ...);"
                " pass --overwrite to replace them"
            )
    return earlier


def input_camera(args: PredictArgs, detections: detection_file.DetectionFile) -> intrinsics.CameraIntrinsics:
    """--intrinsics, or the input's camera per pose (not both), with --image-size where given."""
    camera = intrinsics.CameraIntrinsics() if args.intrinsics is None else intrinsics.read_intrinsics(args.intrinsics)
    if detections.intrinsics is not None:
        if camera.K is not None:
            raise ValueError(f"{args.input} holds a camera per pose ('K'); do not pass --intrinsics as well")
        camera = dataclasses.replace(camera, K=detections.intrinsics)
    return dataclasses.replace(camera, image_size=args.image_size or camera.image_size)


def input_layout(skeleton, detections: detection_file.DetectionFile) -> str | None:
    """The layout the input is read in where --format does not name it: None for an .npz (the checkpoint's
    own joints); for a detector's JSON, the checkpoint's own detector layout (`<layout>_lifting`) where the
    keypoint count fits it (so BODY_25B reads as such for a lifter trained on it), else the one the count
    tells (`jaxpose.layouts.infer_layout`, which refuses to tell BODY_25 from BODY_25B)."""
    if detections.kind == "npz":
        return None
    joints = detections.keypoints.shape[1]
    own = layout_of(skeleton)
    if own is not None and joints == len(layout_joint_names(own)):
        return own
    return infer_layout(3 * joints, str(detections.source), flag="--format")


def input_joint_names(layout: str | None, lifter_joints: Sequence[str], count: int) -> Sequence[str]:
    """The names of the input's `count` joints, for the reports: the layout's (None: the lifter's own)."""
    names = layout_joint_names(layout) if layout is not None else lifter_joints
    return names if len(names) == count else tuple(f"joint {j}" for j in range(count))


def lift_frames(
    lifter, keypoints, confidence, camera: intrinsics.CameraIntrinsics, reject: float | None, flip: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """A frame lifter's poses f32[N, J, 3], in blocks of `LIFT_BLOCK` (a progress bar for more), and the
    joints bool[N, J] that `reject` (--reject-inconsistent; None: off) lifted as missing; `flip`: --flip."""
    count = len(keypoints)
    poses = np.empty((count, lifter.num_joints, 3), np.float32)
    rejected = np.zeros(confidence.shape, bool)
    with tqdm(total=count, desc="lifting", unit="pose", disable=count <= LIFT_BLOCK) as bar:
        for start in range(0, count, LIFT_BLOCK):
            rows = slice(start, min(start + LIFT_BLOCK, count))
            inputs = lifter.prepare(keypoints[rows], camera.of_poses(rows), confidence[rows], camera.dist, camera.image_size)
            if reject is not None:
                rejected[rows] = lifter.inconsistent_joints(inputs, threshold=reject)
                inputs = inputs.without(rejected[rows])
            poses[rows] = lifter.lift(inputs, flip=flip)
            bar.update(rows.stop - rows.start)
    return poses, rejected


def lift_sequence(
    lifter, keypoints, confidence, camera: intrinsics.CameraIntrinsics, detections: detection_file.DetectionFile, flip: bool = False
) -> tuple[np.ndarray, int]:
    """A temporal lifter's poses f32[N, J, 3] and how many of them were not followed: the input's frames
    in sequence order (`lifting_figures.animation_frames`: OpenPose frames in frame-number order, image ids in numerical
    order), one person per frame (the highest mean score), each lifted with the window of frames around
    it; a frame without a pose is a frame of missing joints in its neighbours' windows.  The other
    people's poses are NaN, and said so."""
    count = len(keypoints)
    # Ranked by score alone: nothing is lifted yet.
    frames, shown = lifting_figures.animation_frames(detections.image_ids, confidence, np.ones(count, bool), detections.frame_ids)
    rows = np.array([count if index is None else index for index in shown])
    blank_keypoints = np.concatenate([keypoints, np.zeros((1, *keypoints.shape[1:]), np.float32)])
    blank_confidence = np.concatenate([confidence, np.zeros((1, confidence.shape[1]), np.float32)])
    K = camera.of_poses(np.minimum(rows, count - 1))  # a blank frame's camera is never used: it has no root
    lifted = lifter.predict(blank_keypoints[rows], K, blank_confidence[rows], camera.dist, camera.image_size, flip=flip)
    poses = np.full((count, lifter.num_joints, 3), np.nan, np.float32)
    followed = rows < count
    poses[rows[followed]] = lifted[followed]
    others = count - int(followed.sum())
    print(
        f"temporal lifter ({lifter.model_config.temporal_window} frames): lifted {len(frames)} frames as one sequence"
        + (f"; {others} poses of other people in frames with several are not lifted (null)" if others else ""),
        file=sys.stderr,
    )
    return poses, others


def _count(number: int, noun: str) -> str:
    return f"{number} {noun}" + ("" if number == 1 else "s")


def rejection_report(rejected: np.ndarray, keypoints: np.ndarray, names: Sequence[str], threshold: float) -> str:
    """What --reject-inconsistent lifted as missing (rejected bool[N, J], in the lifter's joints)."""
    if not rejected.any():
        return f"no joint lay farther than --reject-inconsistent {threshold:g} from where the rest of its pose puts it"
    pose, joint = np.argwhere(rejected)[0]
    return (
        f"lifted {_count(int(rejected.sum()), 'joint')} as missing (at most one per pose) that lay farther than"
        f" --reject-inconsistent {threshold:g} median joint-to-root distances from where the rest of the pose puts"
        f" it (first: pose {pose}, {names[joint]} at {[round(float(v), 1) for v in keypoints[pose, joint]]})"
    )


def drop_implausible(
    keypoints: np.ndarray,
    scores: np.ndarray,
    names: Sequence[str],
    image_size: tuple[float, float] | None,
    min_confidence: float,
    outside_margin: float | None,
) -> tuple[np.ndarray, str]:
    """The input's scores with the joints that cannot be right set to 0 (`inference.implausible_joints`
    with --min-confidence and --outside-margin), and a report of them per reason naming the joints by `names`."""
    scores = np.asarray(scores, np.float32)
    dropped = inference.implausible_joints(keypoints, scores, image_size, outside_margin, min_confidence)
    descriptions = {
        "non_finite": "NaN or infinite coordinates with a positive score, or a NaN or infinite score",
        "low_confidence": f"score below --min-confidence {min_confidence:g}",
        "outside_image": (
            f"more than --outside-margin {outside_margin:g} of the larger image side outside the image"
            if image_size is not None and outside_margin is not None else "outside the image"
        ),
    }  # fmt: skip
    parts = []
    for reason in inference.MISSING_REASONS:
        mask = dropped[reason]
        if mask.any():
            pose, joint = np.argwhere(mask)[0]
            parts.append(
                f"{_count(int(mask.sum()), 'joint')} of {_count(int(mask.any(1).sum()), 'pose')}: {descriptions[reason]}"
                f" (first: pose {pose}, {names[joint]} at {[round(float(v), 1) for v in keypoints[pose, joint]]} score"
                f" {float(scores[pose, joint]):.3g})"
            )
    any_dropped = np.any([dropped[reason] for reason in inference.MISSING_REASONS], axis=0)
    count = len(keypoints)
    if parts:
        message = (
            f"treated {_count(int(any_dropped.sum()), 'joint')} of {int(any_dropped.any(1).sum())} of {count} poses as"
            " missing: "
            + "; ".join(parts)
        )
    else:
        message = f"no keypoint of the {count} poses was treated as missing"
    if image_size is None and outside_margin is not None:
        message += " (no image size, so keypoints outside the image were not looked for: pass --image-size W H)"
    return np.where(any_dropped, 0.0, scores).astype(np.float32), message


def main(argv: Sequence[str] | None = None) -> np.ndarray:
    """Entry point; input, checkpoint and shape errors end the process with a one-line message."""
    args, run_dir, _ = inference.parse_with_run(PredictArgs, argv, __doc__, "python -m jaxpose.predict")
    show_logs()
    enable_compilation_cache()  # the lifter's programs from disk on the next run
    try:
        return run(args, run_dir)
    except (ValueError, FileNotFoundError, CheckpointError) as error:
        raise SystemExit(f"jaxpose.predict: error: {error}") from None


if __name__ == "__main__":
    main()
