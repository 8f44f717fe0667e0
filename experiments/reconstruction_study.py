"""How accurate is `jaxpose.reconstruct`'s motion against the multi-camera tools' triangulation?  World-frame
MPJPE (no alignment: this is motion capture, the position matters) on a rig project's held-out part with
ground truth, split by the number of views that detected each joint (0, 1, 2, 3+).

    python -m experiments.reconstruction_study --checkpoint RUN --data.root PROJECT --fps 50 --output DIR \\
        --data.validation-recordings ...       # the part evaluated: the project's held-out part

Methods, on the same detections (each recording on its whole frame axis, every instant of the held-out
part: keep --data.validation-stride 1):
- fused: `jaxpose.reconstruction` as `jaxpose.reconstruct --no-smoothing` runs it, each instant alone (gaps
  up to --max-gap interpolated, and joints no view detects for that long);
- trajectory: the same per-instant evidence solved over time (`jaxpose.reconstruction.trajectory`, as
  `jaxpose.reconstruct` runs it by default, --trajectory.* its settings);
- triangulation: the confidence-weighted DLT of the views scored at least --threshold, where two or more
  are (Pose2Sim's likelihood threshold 0.3); gaps left;
- triangulation, gaps filled: the same, gaps up to --max-gap interpolated linearly, then the last value
  held (and the first held backwards), as Pose2Sim's users fill them (pose2sim#143);
- RANSAC pseudo-labels: `jaxpose.robust.pseudo_labels` "ransac" (at least two agreeing views);
- most confident view: at each instant the lift of the view with the highest mean confidence, placed by
  the fusion's rule (its root and scale, as the fused motion places that view), no oracle.

Conditions: the detections as they are, and with occlusion simulated (seeded): each camera's joint missing
for stretches of --occlusion.min-s to --occlusion.max-s seconds starting at --occlusion.joint-rate per
second, a whole camera dropped for such stretches at --occlusion.camera-rate per second.  The lifts are
of the occluded detections.  Each table gives, per method and view-count bucket, the share of the cells
(instant x joint with ground truth) it has a value for, its MPJPE there, and the fused MPJPE on the same
cells (a paired comparison); then per joint; then the gaps (instants a camera sees the person but some
joint has no value), the acceleration error against the ground truth's (mm/frame^2, over the cells with three
consecutive frames of both) and the limbs' length spread over time (std, mm, the mean over limbs and recordings).  Written to DIR/report.md and DIR/report.json.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
from collections.abc import Sequence
from typing import Annotated

import jax
import jax.numpy as jnp
import numpy as np
import tyro
from tqdm.auto import tqdm

from jaxpose import robust

from jaxpose.serving import inference
from jaxpose.camera import projection_matrices
from jaxpose.chunks import map_in_chunks
from jaxpose.compilation_cache import enable_compilation_cache
from jaxpose.formats.outputs import check_report, write_report
from jaxpose.logs import show_logs
from jaxpose.reconstruction.fusion import FusionConfig
from jaxpose.formats.gaps import DEFAULT_MAX_GAP, fill_gaps
from jaxpose.reconstruction.motion_quality import acceleration_error, limb_length_spread
from jaxpose.reconstruction.recording import RecordingInput, lift_and_reconstruct, placed_lifts, recording_inputs, smooth_recording
from jaxpose.reconstruction.trajectory import TrajectoryConfig
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.triangulation import triangulate

METHODS = ("fused", "trajectory", "triangulation", "triangulation, gaps filled", "RANSAC pseudo-labels", "most confident view")
BUCKETS = ("0", "1", "2", "3+")
CHUNK = 4096  # instants per triangulation call: one compilation per method


@dataclasses.dataclass(frozen=True)
class Occlusion:
    """Simulated occlusion of the detections (seeded)."""

    joint_rate: float = 0.5
    """Stretches per second in which one camera misses one joint (each camera and joint on its own)."""
    camera_rate: float = 0.2
    """Stretches per second in which one camera misses the person entirely (each camera on its own)."""
    min_s: float = 0.2
    """Shortest stretch (s)."""
    max_s: float = 1.0
    """Longest stretch (s); lengths uniform in between."""
    seed: int = 0
    """The random stretches' seed (with the recording's index)."""


@dataclasses.dataclass(frozen=True)
class StudyArgs:
    """The study's flags."""

    checkpoint: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory of `experiments.rig` on the project: its lifter."""
    output: Annotated[pathlib.Path, tyro.conf.arg(metavar="DIR")]
    """Folder for report.md and report.json."""
    fps: float
    """Frames per second of the recordings (occlusion stretches are in seconds)."""
    data: RigProjectConfig = RigProjectConfig()
    """The rig project, calibrated, with ground_truth.npz; its held-out part is evaluated (--data.validation-*)."""
    threshold: float = 0.3
    """The triangulation's confidence threshold (Pose2Sim's likelihood_threshold_triangulation)."""
    max_gap: int = DEFAULT_MAX_GAP
    """Gaps up to this many frames are interpolated (fused; triangulation, gaps filled)."""
    fusion: FusionConfig = FusionConfig()
    """The fusion's model (`jaxpose.reconstruction.fusion`)."""
    bridge_lifted: bool = True
    """Fused: a joint no view detects for at most --max-gap frames is interpolated (`jaxpose.reconstruct`'s flag)."""
    trajectory: TrajectoryConfig = TrajectoryConfig()
    """The trajectory's model (`jaxpose.reconstruction.trajectory`)."""
    occlusion: Occlusion = Occlusion()
    """The simulated occlusion of the second condition."""
    max_frames: int = 0
    """Evaluate the first this many frames of each recording (0: all): a shorter run."""
    overwrite: bool = False
    """Replace DIR/report.md and report.json."""


def first_frames(inputs: RecordingInput, count: int) -> RecordingInput:
    """The recording's first `count` frames (all of them where count is 0)."""
    if not count:
        return inputs
    keep = slice(0, count)
    target = None if inputs.target3d is None else inputs.target3d[keep]
    return dataclasses.replace(
        inputs, frames=inputs.frames[keep], keypoints=inputs.keypoints[keep], confidence=inputs.confidence[keep], target3d=target
    )


def occlude(inputs: RecordingInput, config: Occlusion, fps: float, seed: Sequence[int]) -> RecordingInput:
    """The recording with stretches of missing detections (module docstring): confidence 0 there."""
    rng = np.random.default_rng([config.seed, *seed])
    F, C, J = inputs.confidence.shape
    missing = np.zeros((F, C, J), bool)

    def stretches(rate: float, count: int) -> list[tuple[int, slice]]:  # (unit, frames) per stretch
        starts = rng.poisson(rate * F / fps, count)
        found = []
        for unit, number in enumerate(starts):
            for start, length in zip(rng.integers(0, F, number), rng.uniform(config.min_s, config.max_s, number) * fps):
                found.append((unit, slice(int(start), int(start + round(length)))))
        return found

    for unit, frames in stretches(config.joint_rate, C * J):
        missing[frames, unit // J, unit % J] = True
    for camera, frames in stretches(config.camera_rate, C):
        missing[frames, camera] = True
    confidence = np.where(missing, 0.0, inputs.confidence).astype(np.float32)
    return dataclasses.replace(inputs, confidence=confidence, keypoints=np.where(missing[..., None], 0.0, inputs.keypoints))


@functools.partial(jax.jit, static_argnames="method")
def _triangulated(P, keypoints, confidence, method: str):
    """(points [n, J, 3], known [n, J]) of one chunk: "dlt" (views given with confidence, >= 2) or "ransac"."""
    if method == "ransac":
        points, weight = robust.pseudo_labels(P, keypoints, confidence, "ransac")
        return points, weight > 0
    return triangulate(P, keypoints, confidence), (confidence > 0).sum(-2) >= 2


def triangulations(inputs: RecordingInput, threshold: float, max_gap: int) -> dict[str, np.ndarray]:
    """The three triangulation baselines of the module docstring, f32[F, J, 3] world mm, NaN where none."""
    P = np.broadcast_to(np.asarray(projection_matrices(inputs.cameras)), (len(inputs.frames), *inputs.cameras.K.shape[:1], 3, 4))
    thresholded = np.where(inputs.confidence >= threshold, inputs.confidence, 0.0).astype(np.float32)
    found = {}
    for name, method, confidence in (("triangulation", "dlt", thresholded), ("RANSAC pseudo-labels", "ransac", inputs.confidence)):
        points, known = map_in_chunks(
            lambda *rows, method=method: jax.device_get(_triangulated(*map(jnp.asarray, rows), method=method)),
            (P, inputs.keypoints, confidence), CHUNK,
        )  # fmt: skip
        found[name] = np.where(known[..., None], points, np.nan).astype(np.float32)
    found["triangulation, gaps filled"] = held_filled(found["triangulation"], max_gap)
    return found


def held_filled(points: np.ndarray, max_gap: int) -> np.ndarray:
    """Pose2Sim's users' gap filling: linear up to `max_gap` frames, then the last value held forwards
    (and the first value backwards before it); a joint never known stays NaN."""
    values = fill_gaps(points, max_gap).values
    F = len(values)
    known = np.isfinite(values).all(-1)  # [F, J]
    last = np.maximum.accumulate(np.where(known, np.arange(F)[:, None], -1), axis=0)
    first = np.flip(np.minimum.accumulate(np.flip(np.where(known, np.arange(F)[:, None], F), 0), axis=0), 0)
    source = np.where(last >= 0, last, first)
    source = np.where(source < F, source, 0)
    held = np.take_along_axis(values, source[..., None], 0)
    return np.where(known.any(0)[None, :, None], held, np.nan).astype(np.float32)


def most_confident_view(inputs: RecordingInput, lifted: np.ndarray, placement: np.ndarray) -> np.ndarray:
    """f32[F, J, 3]: each instant's lift of the view with the highest mean confidence, placed as the
    fusion placed that view (`placed_lifts`); NaN where that view's lift did not count."""
    view = inputs.confidence.mean(-1).argmax(-1)  # [F]
    return placed_lifts(inputs.cameras, lifted, placement)[np.arange(len(view)), view]


class Tally:
    """Sums of errors per method, view-count bucket and joint, over cells with ground truth."""

    def __init__(self, joints: int):
        self.error = {m: np.zeros((len(BUCKETS), joints)) for m in METHODS}
        self.covered = {m: np.zeros((len(BUCKETS), joints)) for m in METHODS}
        self.common = {m: np.zeros((len(BUCKETS), joints)) for m in METHODS}  # cells the method and fused cover
        self.common_error = {m: np.zeros((len(BUCKETS), joints)) for m in METHODS}
        self.common_fused = {m: np.zeros((len(BUCKETS), joints)) for m in METHODS}
        self.cells = np.zeros((len(BUCKETS), joints))
        self.gaps = dict.fromkeys(METHODS, 0)
        self.acceleration = {m: np.zeros(2) for m in METHODS}  # summed error, cells
        self.spreads = {m: [] for m in METHODS}  # per recording, the mean limb-length std
        self.seen = 0

    def add(self, results: dict[str, np.ndarray], truth: np.ndarray, views: np.ndarray, seen: np.ndarray, bones) -> None:
        bucket = np.minimum(views, 3)  # [F, J]
        labelled = np.isfinite(truth).all(-1)
        fused_error = np.linalg.norm(results["fused"] - truth, axis=-1)
        self.seen += int(seen.sum())
        for b in range(len(BUCKETS)):
            cells = labelled & (bucket == b)
            self.cells[b] += cells.sum(0)
            for method, points in results.items():
                error = np.linalg.norm(points - truth, axis=-1)
                covered = cells & np.isfinite(error)
                self.covered[method][b] += covered.sum(0)
                self.error[method][b] += np.where(covered, error, 0.0).sum(0)
                common = covered & np.isfinite(fused_error)
                self.common[method][b] += common.sum(0)
                self.common_error[method][b] += np.where(common, error, 0.0).sum(0)
                self.common_fused[method][b] += np.where(common, fused_error, 0.0).sum(0)
        for method, points in results.items():
            self.gaps[method] += int((seen & ~np.isfinite(points).all((-1, -2))).sum())
            self.acceleration[method] += acceleration_error(points, truth)
            spread = limb_length_spread(points, bones)
            if np.isfinite(spread).any():
                self.spreads[method].append(float(np.nanmean(spread)))

    def summary(self, joint_names: Sequence[str]) -> dict:
        def mean(total, count):
            return float(total.sum() / count.sum()) if count.sum() else None

        table = {}
        for method in METHODS:
            table[method] = {
                "buckets": {
                    label: {
                        "cells": int(self.cells[b].sum()),
                        "covered_pct": 100.0 * self.covered[method][b].sum() / max(self.cells[b].sum(), 1),
                        "mpjpe_mm": mean(self.error[method][b], self.covered[method][b]),
                        "common_cells": int(self.common[method][b].sum()),
                        "mpjpe_on_common_cells_mm": mean(self.common_error[method][b], self.common[method][b]),
                        "fused_on_common_cells_mm": mean(self.common_fused[method][b], self.common[method][b]),
                    }
                    for b, label in enumerate(BUCKETS)
                },
                "overall_mm": mean(self.error[method], self.covered[method]),
                "covered_pct": 100.0 * self.covered[method].sum() / max(self.cells.sum(), 1),
                "per_joint_mm": {
                    name: mean(self.error[method][:, j], self.covered[method][:, j]) for j, name in enumerate(joint_names)
                },
                "instants_with_a_gap": self.gaps[method],
                "acceleration_error_mm_per_frame2": mean(*self.acceleration[method]),
                "limb_length_std_mm": float(np.mean(self.spreads[method])) if self.spreads[method] else None,
            }
        return {"instants_seen": self.seen, "methods": table}


def evaluate(args: StudyArgs, lifter: inference.Lifter3D, dataset, occluded: bool) -> dict:
    """One condition over every recording of the held-out part."""
    tally = Tally(dataset.skeleton.num_joints)
    recordings = list(recording_inputs(dataset))
    for index, inputs in enumerate(tqdm(recordings, desc="occluded" if occluded else "as it is", unit="recording")):
        inputs = first_frames(inputs, args.max_frames)
        if occluded:
            inputs = occlude(inputs, args.occlusion, args.fps, (index,))
        motion, lifted = lift_and_reconstruct(lifter, inputs, args.fusion, args.max_gap, args.bridge_lifted)
        smooth = smooth_recording(inputs, motion.fusion, lifter.skeleton.bones, args.fps, args.trajectory, args.max_gap)
        results = {"fused": motion.points, "trajectory": smooth.points, **triangulations(inputs, args.threshold, args.max_gap)}
        results["most confident view"] = most_confident_view(inputs, lifted, motion.fusion.placement)
        views = (inputs.confidence > 0).sum(1)
        tally.add({m: results[m] for m in METHODS}, inputs.target3d, views, inputs.seen, lifter.skeleton.bones)
    return tally.summary(dataset.skeleton.joint_names)


def report_markdown(report: dict) -> str:
    lines = ["# Reconstruction study", "", report["setup"], ""]
    for condition, result in report["conditions"].items():
        lines += [f"## {condition}", "", f"Instants some camera sees: {result['instants_seen']}.", ""]
        header = "| method | " + " | ".join(f"{b} views: covered %, MPJPE / fused's (common cells)" for b in BUCKETS)
        lines += [header + " | overall MPJPE (covered %) | instants with a gap | accel. error (mm/frame^2) | limb length std (mm) |",
                  "|---" * (len(BUCKETS) + 5) + "|"]  # fmt: skip
        for method, row in result["methods"].items():
            cells = []
            for bucket in row["buckets"].values():
                if not bucket["cells"]:
                    cells.append("no cells")
                elif bucket["mpjpe_on_common_cells_mm"] is None:
                    cells.append(f"{bucket['covered_pct']:.0f}%, -")
                else:
                    paired = f"{bucket['mpjpe_on_common_cells_mm']:.1f} / {bucket['fused_on_common_cells_mm']:.1f}"
                    cells.append(f"{bucket['covered_pct']:.0f}%, {paired}")
            overall = "-" if row["overall_mm"] is None else f"{row['overall_mm']:.1f}"
            motion = " | ".join("-" if row[key] is None else f"{row[key]:.2f}" for key in ("acceleration_error_mm_per_frame2", "limb_length_std_mm"))
            lines.append(f"| {method} | " + " | ".join(cells) + f" | {overall} ({row['covered_pct']:.0f}%) | {row['instants_with_a_gap']} | {motion} |")
        counts = ", ".join(f"{b} views {bucket['cells']}" for b, bucket in zip(BUCKETS, result["methods"]["fused"]["buckets"].values()))
        lines += ["", f"Cells (instant x joint with ground truth): {counts}.", ""]
        joints = list(result["methods"]["fused"]["per_joint_mm"])
        lines += ["| method | " + " | ".join(joints) + " |", "|---" * (len(joints) + 1) + "|"]
        for method, row in result["methods"].items():
            values = ["-" if v is None else f"{v:.1f}" for v in row["per_joint_mm"].values()]
            lines.append(f"| {method} | " + " | ".join(values) + " |")
        lines.append("")
    return "\n".join(lines)


def run(args: StudyArgs) -> dict:
    check_report(args.output, args.overwrite)
    lifter = inference.load(args.checkpoint)
    project = load_rig_project(args.data, progress=True)
    if project.recovered_calibration is not None or project.validation.samples.target3d is None:
        raise ValueError(f"{args.data.root}: the study needs a calibrated project with ground_truth.npz (world mm)")
    dataset = project.validation
    held_out = ", ".join(args.data.validation_recordings) or f"the last {args.data.validation_fraction:.0%} of every recording"
    setup = (
        f"Lifter {args.checkpoint} (step {lifter.step}); project {args.data.root}, held-out part ({held_out}), every"
        f" {args.data.validation_stride} instant(s), {len(dataset)} instants"
        f"{f' (the first {args.max_frames} frames of each recording evaluated)' if args.max_frames else ''}; world-frame MPJPE (mm, no alignment) over the"
        f" joints with ground truth ({', '.join(project.ground_truth_joints)}); views = detections with confidence > 0;"
        f" triangulation threshold {args.threshold}; gaps up to {args.max_gap} frames interpolated (lifted-only joints"
        f" {'too' if args.bridge_lifted else 'not'}); fusion"
        f" {dataclasses.asdict(args.fusion)}; trajectory {dataclasses.asdict(args.trajectory)}; occlusion {dataclasses.asdict(args.occlusion)} at {args.fps:g} fps."
    )
    conditions = {"As it is": evaluate(args, lifter, dataset, False), "Occluded": evaluate(args, lifter, dataset, True)}
    report = {"setup": setup, "conditions": conditions}
    markdown = report_markdown(report)
    write_report(args.output, report, markdown)
    return report


def main(argv: Sequence[str] | None = None) -> dict:
    args = tyro.cli(StudyArgs, args=argv, description=__doc__, prog="python -m experiments.reconstruction_study")
    show_logs()
    enable_compilation_cache()
    return run(args)


if __name__ == "__main__":
    main()
