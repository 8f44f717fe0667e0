"""The trajectory's settings chosen on recordings that are never reported: a grid of `TrajectoryConfig`s
scored by world MPJPE per view-count bucket and acceleration error, each recording lifted and fused once.

    python -m experiments.trajectory_tuning --checkpoint RUN --data.root PROJECT --fps 50 --output DIR \\
        --data.validation-recordings ...   # the tuning recordings (the lifter of RUN did not train on them)

Conditions as `experiments.reconstruction_study`'s (the detections as they are, and with its simulated
occlusion, here with --occlusion.seed, 1 by default: another draw than the study's).  Each grid point
changes one setting of the default `TrajectoryConfig` (a one-at-a-time scan), plus the per-instant
fusion as the reference.  Written to DIR/report.md and DIR/report.json.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Sequence
from typing import Annotated

import numpy as np
import tyro
from tqdm.auto import tqdm

from experiments.reconstruction_study import BUCKETS, Occlusion, first_frames, occlude
from jaxpose.serving import inference
from jaxpose.compilation_cache import enable_compilation_cache
from jaxpose.formats.outputs import check_report, write_report
from jaxpose.logs import show_logs
from jaxpose.reconstruction.motion_quality import acceleration_error, limb_length_spread
from jaxpose.reconstruction.recording import lift_and_reconstruct, recording_inputs, smooth_recording
from jaxpose.reconstruction.trajectory import TrajectoryConfig
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig


@dataclasses.dataclass(frozen=True)
class TuningArgs:
    """The tuning's flags."""

    checkpoint: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory of `experiments.rig`: a lifter that did not train on the tuning recordings."""
    output: Annotated[pathlib.Path, tyro.conf.arg(metavar="DIR")]
    """Folder for report.md and report.json."""
    fps: float
    """Frames per second of the recordings."""
    data: RigProjectConfig = RigProjectConfig()
    """The rig project, calibrated, with ground_truth.npz; its held-out part (--data.validation-*) is tuned on."""
    acceleration_mm_s2: tuple[float, ...] = (1000.0, 3000.0, 10000.0, 30000.0)
    """The process noises scanned (each fixed for every joint; the default estimates it per recording)."""
    acceleration_dof: tuple[float, ...] = (2.0, 8.0, float("inf"))
    """The acceleration's Student-t degrees of freedom scanned (inf: Gaussian)."""
    limb_sigma_mm: tuple[float, ...] = (3.0, 10.0, 30.0, 1e6)
    """The limb-length sigmas scanned (1e6: no limb term)."""
    robust_sigmas: tuple[float, ...] = (1.5, 3.0, 6.0, 1e6)
    """The robust scales scanned (1e6: no re-weighting)."""
    lifted_sigma_scale: tuple[float, ...] = (1.0, 2.0, 4.0)
    """The lifted-only cells' uncertainty factors scanned."""
    max_frames: int = 0
    """Tune on the first this many frames of each recording (0: all)."""
    occlusion: Occlusion = Occlusion(seed=1)
    """The simulated occlusion (another seed than the study's)."""
    overwrite: bool = False
    """Replace DIR/report.md and report.json."""


def grid(args: TuningArgs) -> dict[str, TrajectoryConfig | None]:
    """The per-instant fusion (None), the default, and the default with one setting changed at a time."""
    default = TrajectoryConfig()
    configs: dict[str, TrajectoryConfig | None] = {"per-instant fusion": None, "default": default}
    for name in ("acceleration_mm_s2", "acceleration_dof", "limb_sigma_mm", "robust_sigmas", "lifted_sigma_scale"):
        for value in getattr(args, name):
            if value != getattr(default, name):
                configs[f"{name} {value:g}"] = dataclasses.replace(default, **{name: value})
    return configs


class Scores:
    """Sums of world errors per bucket, of acceleration errors and of limb-length spreads."""

    def __init__(self):
        self.error, self.cells = np.zeros(len(BUCKETS)), np.zeros(len(BUCKETS))
        self.acceleration, self.acceleration_cells, self.spreads = 0.0, 0, []

    def add(self, points, truth, views, bones):
        error = np.linalg.norm(points - truth, axis=-1)
        bucket = np.minimum(views, 3)
        for b in range(len(BUCKETS)):
            cells = (bucket == b) & np.isfinite(error)
            self.error[b] += error[cells].sum()
            self.cells[b] += cells.sum()
        total, count = acceleration_error(points, truth)
        self.acceleration += total
        self.acceleration_cells += count
        self.spreads.append(np.nanmean(limb_length_spread(points, bones)))

    def row(self) -> dict:
        buckets = {label: float(self.error[b] / self.cells[b]) if self.cells[b] else None for b, label in enumerate(BUCKETS)}
        return {
            "buckets_mm": buckets,
            "overall_mm": float(self.error.sum() / max(self.cells.sum(), 1)),
            "acceleration_error_mm_per_frame2": self.acceleration / max(self.acceleration_cells, 1),
            "limb_length_std_mm": float(np.mean(self.spreads)),
        }


def run(args: TuningArgs) -> dict:
    check_report(args.output, args.overwrite)
    lifter = inference.load(args.checkpoint)
    project = load_rig_project(args.data, progress=True)
    if project.validation.samples.target3d is None:
        raise ValueError(f"{args.data.root}: tuning needs ground_truth.npz (world mm)")
    configs = grid(args)
    bones = lifter.skeleton.bones
    report = {"recordings": list(args.data.validation_recordings), "max_frames": args.max_frames, "conditions": {}}
    for occluded in (False, True):
        scores = {name: Scores() for name in configs}
        recordings = list(recording_inputs(project.validation))
        for index, inputs in enumerate(tqdm(recordings, desc="occluded" if occluded else "as it is", unit="recording")):
            inputs = first_frames(inputs, args.max_frames)
            if occluded:
                inputs = occlude(inputs, args.occlusion, args.fps, (index,))
            motion, _ = lift_and_reconstruct(lifter, inputs)
            views = (inputs.confidence > 0).sum(1)
            for name, config in configs.items():
                points = motion.points if config is None else smooth_recording(inputs, motion.fusion, bones, args.fps, config).points
                scores[name].add(points, inputs.target3d, views, bones)
        report["conditions"]["Occluded" if occluded else "As it is"] = {name: s.row() for name, s in scores.items()}
    lines = ["# Trajectory tuning", "", f"Recordings {', '.join(report['recordings'])}; first {args.max_frames or 'all'} frames.", ""]
    for condition, rows in report["conditions"].items():
        lines += [f"## {condition}", "", "| setting | " + " | ".join(f"{b} views" for b in BUCKETS)
                  + " | overall | accel. error (mm/frame^2) | limb std (mm) |", "|---" * (len(BUCKETS) + 4) + "|"]  # fmt: skip
        for name, row in rows.items():
            buckets = " | ".join("-" if v is None else f"{v:.1f}" for v in row["buckets_mm"].values())
            lines.append(
                f"| {name} | {buckets} | {row['overall_mm']:.1f} | {row['acceleration_error_mm_per_frame2']:.2f} | {row['limb_length_std_mm']:.1f} |"
            )
        lines.append("")
    markdown = "\n".join(lines)
    write_report(args.output, report, markdown)
    return report


def main(argv: Sequence[str] | None = None) -> dict:
    args = tyro.cli(TuningArgs, args=argv, description=__doc__, prog="python -m experiments.trajectory_tuning")
    show_logs()
    enable_compilation_cache()
    return run(args)


if __name__ == "__main__":
    main()
