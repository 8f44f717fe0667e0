"""Reconstruction over time on real motion: CMU motion capture seen through simulated rigs and detector.

    python -m benchmarks.motion --output runs/motion --checkpoint RUN

Each take of `--data` (the CMU BVH files of ../shared/data/cmu_mocap, 120 fps; `jaxpose.formats.bvh`) is
mapped to COCO-17 keypoints (`jaxpose.synthetic.mocap`: which keypoints are CMU joints and how the face
points are placed), cut to its first `--max-frames` mocap frames (`--full`: whole takes, every file),
sampled at each of `--rates` (every 4th, 2nd or 1st frame for 30, 60, 120 fps), and seen by the example
rig project's simulated rig of `--cameras` cameras (`jaxpose.synthetic.capture.rig_calibration`, pinhole,
the rig of seed 0) through its simulated detector (`jaxpose.synthetic.capture.detect`: per-joint noise,
gross outliers, missing keypoints, whole-view left/right swaps, keypoints outside an image lost), one
detector draw per `--seeds`.  The recordings are held in memory, not written as project folders.

Methods, all on the same detections: `jaxpose.reconstruct`'s default (the trajectory) and
`--no-smoothing` (per-instant fusion) through `benchmarks.peers.JAXPOSE_METHODS` with the lifter of
`--checkpoint` (a run of `experiments.rig` on a COCO-17 rig project); the peers of `benchmarks.peers`
(Pose2Sim triangulation and its filtering, aniposelib `optim_points` with limb constraints) through its
driver in their own environment (`--venv`; skipped, with a line saying why, where absent).  Scores are
`benchmarks.peers_scores.Scores`' over the pelvis and COCO-17's 17 keypoints: world MPJPE (mm, no
alignment), P-MPJPE (mm), acceleration error (mm/frame^2 at the rate's frames), per kind of motion
(`KINDS`) and rate, as the mean over seeds and their spread (max - min), and the world error split into
its offset (per take and joint, the mean error vector over the instants) and what varies about it.
Beside them, what the default's motion prior estimated (`jaxpose.reconstruct`'s report fields
`motion_prior_mm_s2` and `impacts`, per take and seed in report.json's `priors`): the process noise over
the joints, takes and seeds (median and range, mm/s^2 per axis) and the impacts, the share of
accelerations the Student-t prior weighted below 0.5.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import sys
import time
from collections.abc import Sequence
from typing import Annotated

import jax
import numpy as np
import tyro

from benchmarks.peers import JAXPOSE_METHODS, PEER_METHODS, PeersArgs, peer_families, peer_python, run_peer, write_calibration
from benchmarks.peers_scores import Scores
from jaxpose.formats.bvh import read_bvh
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.outputs import OutputError, check_report, write_report
from jaxpose.layouts import lifting_skeleton, to_lifting_skeleton
from jaxpose.reconstruct import recording_summary
from jaxpose.reconstruction.recording import RecordingInput, lift_and_reconstruct
from jaxpose.reconstruction.trajectory import TrajectoryConfig
from jaxpose.serving import inference
from jaxpose.skeleton import COCO_17
from jaxpose.synthetic.capture import ExampleProjectConfig, detect, field_radius2, rig_calibration
from jaxpose.synthetic.mocap import mocap_keypoints

MOCAP_FPS = 120
DATA = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cmu_mocap"
KINDS = {  # kind of motion -> the takes (subject/take) it holds
    "walk": ("02/02_01", "02/02_02"),
    "jog": ("02/02_03",),
    "rest of 02": tuple(f"02/02_{n:02d}" for n in range(4, 11)),
    "dance": tuple(f"05/05_{n:02d}" for n in range(1, 21)),
    "basketball": tuple(f"06/06_{n:02d}" for n in range(1, 16)),
}
METHOD_NAMES = {"jaxpose trajectory": "jaxpose.reconstruct (default)", "jaxpose per-instant fusion": "jaxpose.reconstruct --no-smoothing"}
DEFAULT_PEERS = ("pose2sim.triangulation", "pose2sim.filtering", "aniposelib.optim_points_limbs")


@dataclasses.dataclass(frozen=True)
class MotionArgs:
    """The benchmark's flags."""

    output: Annotated[pathlib.Path, tyro.conf.arg(metavar="DIR")]
    """Folder for report.md, report.json and the peers' work folders."""
    checkpoint: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory of `experiments.rig` trained on a COCO-17 rig project: the lifter."""
    data: pathlib.Path = DATA
    """The CMU BVH files (subject folders 02, 05, 06)."""
    cameras: int = 4
    """Cameras of the simulated rig (3-8)."""
    rates: tuple[int, ...] = (30, 60)
    """Frame rates (divisors of the mocap's 120 fps: 30 60 120 for all three)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Detector-noise seeds."""
    max_frames: int = 240
    """Each take's first N mocap frames (120 fps), the same span at every rate."""
    takes_per_kind: int = 1
    """The first N takes of each kind."""
    full: bool = False
    """Every take of every kind, whole (overrides --max-frames and --takes-per-kind)."""
    peers: tuple[str, ...] = DEFAULT_PEERS
    """The peers' methods (family.method of benchmarks.peers); none: --peers with no value."""
    venv: pathlib.Path = pathlib.Path.home() / ".cache" / "jaxpose-peers" / "venv"
    """The peers' virtual environment (benchmarks.peers makes it; this benchmark does not)."""
    overwrite: bool = False
    """Replace DIR/report.md and report.json."""


def takes(args: MotionArgs) -> dict[str, tuple[str, ...]]:
    """kind -> the takes benchmarked (present in --data)."""
    chosen = {}
    for kind, names in KINDS.items():
        present = tuple(name for name in names if (args.data / f"{name}.bvh").is_file())
        chosen[kind] = present if args.full else present[: args.takes_per_kind]
    if not any(chosen.values()):
        raise SystemExit(f"--data {args.data}: none of the CMU takes ({KINDS['jog'][0]}.bvh, ...) found")
    return chosen


def rig_config(cameras: int, fps: float, seed: int, frames: int) -> ExampleProjectConfig:
    """The example project's simulation: pinhole cameras, one person, every camera in sync."""
    return ExampleProjectConfig(layout="coco17", cameras=cameras, fps=fps, seed=seed, frames_per_recording=max(frames, 10),
                                distortion=False, desync_camera=-1, second_person_rate=0.0)  # fmt: skip


def seen_by_rig(name: str, points: np.ndarray, cameras: int, fps: float, seed: int, key: int) -> RecordingInput:
    """COCO-17 points f[F, 17, 3] (world mm) through the rig of seed 0 and the detector of `seed`, on the COCO
    lifting skeleton (the pelvis first: the hips' midpoint), with the ground truth likewise."""
    config = rig_config(cameras, fps, seed, len(points))
    rig = rig_calibration(dataclasses.replace(config, seed=0))
    person = detect(config, rig, field_radius2(rig.cameras, config.image_size), points, (key,))
    keypoints, confidence = to_lifting_skeleton("coco17", person.keypoints, person.scores)
    hips = [COCO_17.joint_names.index("left_hip"), COCO_17.joint_names.index("right_hip")]
    truth = np.concatenate([points[:, hips].mean(1, keepdims=True), points], axis=1).astype(np.float32)
    return RecordingInput(name, np.arange(len(points)), rig.cameras, keypoints, confidence, truth)


def recordings(args: MotionArgs, rate: int, seed: int) -> dict[str, dict[str, RecordingInput]]:
    """kind -> take -> its recording at `rate` fps seen through the rig with detector seed `seed`."""
    found: dict[str, dict[str, RecordingInput]] = {}
    for key, (kind, names) in enumerate(takes(args).items()):
        for index, name in enumerate(names):
            path = args.data / f"{name}.bvh"
            try:
                bvh = read_bvh(path)
                span = slice(0, None if args.full else args.max_frames, MOCAP_FPS // rate)
                points = mocap_keypoints(bvh, "coco17", frames=span)
            except (DataFormatError, ValueError) as error:
                raise SystemExit(f"error: {error}" if isinstance(error, DataFormatError) else f"{path}: {error}") from None
            if abs(bvh.fps - MOCAP_FPS) > 0.1:
                raise SystemExit(f"{path}: {bvh.fps:.2f} fps, expected {MOCAP_FPS}")
            found.setdefault(kind, {})[name] = seen_by_rig(name, points, args.cameras, rate, seed, 100 * key + index)
    return found


def score(points: np.ndarray, inputs: RecordingInput, scores: Scores) -> None:
    views = (inputs.confidence > 0).sum(1)
    scores.add(points, inputs.target3d, views, inputs.seen, lifting_skeleton("coco17").bones)


def estimated_prior(lifter: inference.Lifter3D, inputs: RecordingInput, rate: int) -> dict:
    """What the default's motion prior estimated on `inputs` (`benchmarks.peers`' trajectory solved again, kept
    whole): its joints' process noise (mm/s^2), its impacts and of how many accelerations."""
    motion = lift_and_reconstruct(lifter, inputs, trajectory=TrajectoryConfig(), fps=float(rate))[0]
    summary = recording_summary(motion, lifter.joint_names)
    return {"motion_prior_mm_s2": summary["motion_prior_mm_s2"], "impacts": summary["impacts"],
            "accelerations": int(np.isfinite(motion.impact_weight).sum())}  # fmt: skip


def run(args: MotionArgs) -> dict:
    if not 3 <= args.cameras <= 8:
        raise SystemExit(f"--cameras {args.cameras}: expected 3 to 8")
    if any(MOCAP_FPS % rate for rate in args.rates):
        raise SystemExit(f"--rates {' '.join(map(str, args.rates))}: expected divisors of the mocap's {MOCAP_FPS} fps")
    try:
        check_report(args.output, args.overwrite)
    except OutputError as error:
        raise SystemExit(f"error: {error}") from None
    try:
        lifter = inference.load(args.checkpoint)
    except (FileNotFoundError, ValueError) as error:
        raise SystemExit(f"error: --checkpoint: {error}") from None
    skeleton = lifting_skeleton("coco17")
    if tuple(lifter.joint_names) != skeleton.joint_names:
        raise SystemExit(f"--checkpoint {args.checkpoint}: lifts {tuple(lifter.joint_names)}, not COCO-17's lifting skeleton")
    families = peer_families(PeersArgs(output=args.output, checkpoint=args.checkpoint, peers=args.peers))
    python, peers = (None, "no peer chosen (--peers)") if not families else peer_python(
        PeersArgs(output=args.output, checkpoint=args.checkpoint, venv=args.venv, install=False))  # fmt: skip
    if python is None:
        print(f"peers skipped: {peers}", file=sys.stderr)
    args.output.mkdir(parents=True, exist_ok=True)
    rig = rig_calibration(rig_config(args.cameras, MOCAP_FPS, 0, 10))
    calibration = write_calibration(args.output / "calibration.toml", rig.camera_names, rig.cameras, rig.image_size,
                                    rig.source, overwrite=True)  # fmt: skip
    agreeing = np.ones(skeleton.num_joints, bool)
    started = time.perf_counter()
    cells: dict[str, dict[str, dict[str, list[dict]]]] = {}  # kind -> rate -> method -> [summary per seed]
    priors: dict[str, dict[str, list[dict]]] = {}  # kind -> rate -> [take -> estimated prior, per seed]
    for rate in args.rates:
        for seed in args.seeds:
            found = recordings(args, rate, seed)
            results = {kind: {name: {METHOD_NAMES[method]: function(lifter, inputs, float(rate))
                                     for method, function in JAXPOSE_METHODS.items()}
                              for name, inputs in group.items()}
                       for kind, group in found.items()}  # fmt: skip
            for kind, group in found.items():
                estimated = {name: estimated_prior(lifter, inputs, rate) for name, inputs in group.items()}
                priors.setdefault(kind, {}).setdefault(str(rate), []).append(estimated)
            flat = {name: inputs for group in found.values() for name, inputs in group.items()}
            for family, methods in (families.items() if python else ()):
                work = args.output / "work" / f"{rate}fps_seed{seed}" / family
                peer_args = PeersArgs(output=args.output, checkpoint=args.checkpoint, fps=float(rate))
                output, _, problem = run_peer(python, family, methods, work, calibration, flat, skeleton, peer_args)
                if problem:
                    print(f"{rate} fps, seed {seed}, {family}: {problem} (log: {work / 'driver.log'})", file=sys.stderr)
                for kind, group in found.items():
                    for name in group:
                        for method, points in output.get(name, {}).items():
                            results[kind][name][PEER_METHODS[family][method]] = points
            for kind, group in found.items():
                per_method: dict[str, Scores] = {}
                for name, inputs in group.items():
                    for method, points in {"ground truth": inputs.target3d, **results[kind][name]}.items():
                        score(points, inputs, per_method.setdefault(method, Scores(agreeing)))
                for method, scores in per_method.items():
                    cells.setdefault(kind, {}).setdefault(str(rate), {}).setdefault(method, []).append(scores.summary())
            print(f"{rate} fps, seed {seed}: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    report = {
        "setup": (f"{os.cpu_count()} CPU cores, jax {jax.__version__}; lifter {args.checkpoint} (step {lifter.step});"
                  f" peers: {peers if python else 'skipped, ' + peers}; {args.cameras} cameras; seeds {list(args.seeds)};"
                  f" {'whole takes' if args.full else f'first {args.max_frames} mocap frames of each take'};"
                  f" {time.perf_counter() - started:.0f} s."),
        "takes": takes(args),
        "results": cells,
        "priors": priors,
    }  # fmt: skip
    write_report(args.output, report, markdown(report))
    return report


def _cell(values: list[float | None]) -> str:
    values = [value for value in values if value is not None]
    if not values:
        return ""
    return f"{np.mean(values):.1f} ± {np.ptp(values):.1f}" if len(values) > 1 else f"{values[0]:.1f}"


def markdown(report: dict) -> str:
    """One row per kind of motion, rate and method: the mean over seeds ± their spread (max - min)."""
    lines = [
        report["setup"], "",
        "| motion | takes | fps | method | world MPJPE (mm) | P-MPJPE (mm) | acceleration error (mm/frame²) | coverage (%) |",
        "|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for kind, rates in report["results"].items():
        for rate, methods in rates.items():
            for method, seeds in methods.items():
                if method == "ground truth":
                    continue
                columns = ("mpjpe_mm", "p_mpjpe_mm", "accel_error_mm_per_frame2", "covered_pct")
                cells = [_cell([summary[column] for summary in seeds]) for column in columns]
                lines.append(f"| {kind} | {', '.join(report['takes'][kind])} | {rate} | {method} | {' | '.join(cells)} |")
    lines += [
        "", "The world error split: per take and joint, its mean over the instants (the offset, its norm averaged over the"
        " cells) and what varies about it (mm; mean over seeds ± spread).", "",
        "| fps | motion | method | world MPJPE (mm) | offset (mm) | about the offset (mm) |", "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for kind, rates in report["results"].items():
        for rate, methods in rates.items():
            for method, seeds in methods.items():
                if method != "ground truth":
                    columns = ("mpjpe_mm", "offset_mm", "about_offset_mm")
                    cells = [_cell([summary[column] for summary in seeds]) for column in columns]
                    lines.append(f"| {rate} | {kind} | {method} | {' | '.join(cells)} |")
    lines += [
        "", "The default's motion prior as estimated: each joint's process noise over the joints, takes and seeds (mm/s²"
        " per axis, median (range)) and its impacts (accelerations the Student-t prior weighted below 0.5).", "",
        "| fps | motion | process noise, median (range) (mm/s²) | impacts (% of accelerations) |", "|---|---|---|---|",
    ]  # fmt: skip
    for kind, rates in report["priors"].items():
        for rate, seeds in rates.items():
            solved = [take for seed in seeds for take in seed.values()]
            noise = [value for take in solved for value in take["motion_prior_mm_s2"].values() if value is not None]
            impacts = sum(take["impacts"] for take in solved), sum(take["accelerations"] for take in solved)
            spread = f"{np.median(noise):.0f} ({min(noise):.0f}-{max(noise):.0f})" if noise else "-"
            lines.append(f"| {rate} | {kind} | {spread} | {100 * impacts[0] / max(impacts[1], 1):.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict:
    args = tyro.cli(MotionArgs, args=argv, description=__doc__.split("\n\n")[0], prog="python -m benchmarks.motion")
    return run(args)


if __name__ == "__main__":
    main()
