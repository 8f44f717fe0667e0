"""jaxpose's reconstruction beside Pose2Sim's and aniposelib's, on the same rig project and detections.

    python -m benchmarks.peers --output runs/peers --checkpoint runs/rig_dev_s0 --data.root runs/h36m_s1_rig \
        --data.validation-recordings 'Directions 1' ... --data.train-stride 50 --fps 50

The peers live in a virtual environment of their own (`--venv`, default ~/.cache/jaxpose-peers/venv):
made with `python -m venv` and `pip install pose2sim aniposelib` where absent (`--no-install`: never),
run as subprocesses (`benchmarks/peers_driver.py` with that environment's python) that exchange .npz,
.toml and .json files with this process; jaxpose never imports them.  Without the environment or the
packages, one line says why and the peers are skipped; jaxpose's methods are still measured.

Accuracy (`--part accuracy`): the project's held-out recordings (`--data.validation-*`, as
`experiments.reconstruction_study` takes them; each cut to its first `--max-frames` frames where
given), as they are and with the study's simulated occlusion over `--seeds`.  Each method gets the
same detections: jaxpose the undistorted ones with the pinhole rig, the peers the detections as
detected with the calibration as a TOML in metres, its distortion included (Pose2Sim's default
`undistort_points = false` then ignores it; aniposelib undistorts).  Scores (`Scores`): world MPJPE
(mm, no alignment) on all joints and on those whose definitions agree with the ground truth's
(`--disagreeing-joints` left out), P-MPJPE on the instants a method gives every joint, acceleration
error (mm/frame^2, the second difference against the ground truth's), each limb's length spread over
time (standard deviation, mm), and coverage and MPJPE by the number of views that detected the joint,
and the instants some camera sees that have a gap; and the world error split into each joint's mean
offset per recording and what varies about it (`peers_scores.Scores`).

Timing (`--part timing`): `--cameras` of a synthetic rig (`jaxpose.synthetic`, one recording of
`--timing-frames` frames, detector noise `--noise-scale` times its per-joint sigma and `--outlier-rate`
gross outliers), every method in this one run, one after the other: the first call (with compilation;
JAX's caches cleared before it) and the median of `--repeats` calls after it.  A peer's calls run in
one subprocess stopped after `--peer-limit-s` and reported as capped.

jaxpose's methods are `JAXPOSE_METHODS` (name -> function of the lifter and a recording's inputs
and the recording's fps, giving f32[F, J, 3] world mm): one line adds another.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from typing import Annotated

import jax
import numpy as np
import tyro

from benchmarks.peers_report import report_markdown
from benchmarks.peers_scores import Scores, limb_spread
from experiments.reconstruction_study import Occlusion, occlude
from jaxpose.serving import inference
from jaxpose.camera import Cameras
from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.formats.outputs import check_report, write_report
from jaxpose.formats.calibration_files import find_calibration, read_rig_calibration
from jaxpose.reconstruction.recording import RecordingInput, lift_and_reconstruct, recording_inputs
from jaxpose.reconstruction.trajectory import TrajectoryConfig
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.skeleton import H36M_17, Skeleton
from jaxpose.synthetic import SyntheticConfig, make_rig, project_points, sample_bone_lengths, sample_motion, simulate_detector
from jaxpose.synthetic.config import Stream, stream_rng

DRIVER = pathlib.Path(__file__).with_name("peers_driver.py")
PACKAGES = ("pose2sim", "aniposelib")
PEER_METHODS = {  # family -> driver method -> the name in the tables
    "pose2sim": {"triangulation": "Pose2Sim triangulation", "filtering": "Pose2Sim triangulation + filtering"},
    "aniposelib": {
        "triangulate": "aniposelib triangulate", "triangulate_ransac": "aniposelib triangulate_ransac",
        "optim_points": "aniposelib optim_points", "optim_points_limbs": "aniposelib optim_points, limbs",
    },
}  # fmt: skip


def per_instant(lifter: inference.Lifter3D, inputs: RecordingInput, fps: float) -> np.ndarray:
    """`python -m jaxpose.reconstruct --no-smoothing`'s motion: per-instant fusion, gaps bridged."""
    return lift_and_reconstruct(lifter, inputs)[0].points


def trajectory(lifter: inference.Lifter3D, inputs: RecordingInput, fps: float) -> np.ndarray:
    """`python -m jaxpose.reconstruct`'s motion (its defaults): the trajectory solved over time."""
    return lift_and_reconstruct(lifter, inputs, trajectory=TrajectoryConfig(), fps=fps)[0].points


JAXPOSE_METHODS: dict[str, Callable[[inference.Lifter3D, RecordingInput, float], np.ndarray]] = {
    "jaxpose per-instant fusion": per_instant,
    "jaxpose trajectory": trajectory,
}


@dataclasses.dataclass(frozen=True)
class PeersArgs:
    """The benchmark's flags."""

    output: Annotated[pathlib.Path, tyro.conf.arg(metavar="DIR")]
    """Folder for report.md, report.json and the peers' work folders."""
    checkpoint: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory of `experiments.rig` on the project: the lifter of jaxpose's methods (timing too:
    the synthetic rig's joints are taken by its joint names)."""
    part: tuple[str, ...] = ("accuracy", "timing")
    """accuracy, timing, or both."""
    data: RigProjectConfig = RigProjectConfig()
    """The calibrated rig project with ground_truth.npz; its held-out part is scored."""
    fps: float = 50.0
    """Frames per second of the recordings (occlusion stretches are in seconds; Pose2Sim's filter)."""
    max_frames: int | None = None
    """Score each recording's first N frames only (the peers are slow)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Occlusion seeds (`experiments.reconstruction_study`'s occlusion, its defaults otherwise)."""
    occlusion: Occlusion = Occlusion()
    disagreeing_joints: tuple[str, ...] = ("Spine", "Head")
    """Joints left out of the 'agreeing joints' MPJPE (the Stacked Hourglass's MPII joints under Human3.6M's names)."""
    venv: pathlib.Path = pathlib.Path.home() / ".cache" / "jaxpose-peers" / "venv"
    """The peers' virtual environment."""
    install: bool = True
    """Make the environment (python -m venv; pip install pose2sim aniposelib) where it is absent."""
    peers: tuple[str, ...] = tuple(f"{family}.{method}" for family, methods in PEER_METHODS.items() for method in methods)
    """The peers' methods run (family.method)."""
    threshold: float = 0.3
    """aniposelib: detections below this confidence are dropped (Pose2Sim's own default is 0.3 too)."""
    cameras: tuple[int, ...] = (4, 8, 16, 32)
    """Timing: camera counts of the synthetic rig."""
    timing_frames: int = 250
    """Timing: frames of the synthetic recording."""
    noise_scale: float = 1.0
    """Timing: the synthetic detector's noise, times its per-joint sigma (3-8 px)."""
    outlier_rate: float = 0.02
    """Timing: share of detections replaced by gross outliers (30-150 px off)."""
    repeats: int = 3
    """Timing: calls after the first; the median is reported."""
    peer_limit_s: float = 600.0
    """Timing: a peer method's calls stop after this many seconds (reported as capped)."""
    overwrite: bool = False
    """Replace DIR/report.md and report.json."""


# ----------------------------------------------------------------------------------------------
# The peers' environment and driver


def peer_python(args: PeersArgs) -> tuple[pathlib.Path | None, str]:
    """(the environment's python, the peers' versions), or (None, why not) in one line."""
    python = args.venv / "bin" / "python"
    if not python.exists():
        if not args.install:
            return None, f"no virtual environment at {args.venv} (without --no-install the benchmark makes it)"
        for command in ([sys.executable, "-m", "venv", str(args.venv)], [str(python), "-m", "pip", "install", "-q", *PACKAGES]):
            try:
                done = subprocess.run(command, capture_output=True, text=True)
            except OSError as error:
                return None, f"{' '.join(command[:4])}: {error}"
            if done.returncode:
                last = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
                return None, f"{' '.join(command[:4])} failed: {last}"
    check = (
        "import importlib.metadata as m, Pose2Sim, aniposelib;"
        " print(', '.join(p + ' ' + m.version(p) for p in ('pose2sim', 'aniposelib')))"
    )
    try:
        done = subprocess.run([str(python), "-c", check], capture_output=True, text=True, env=peer_environment())
    except OSError as error:
        return None, f"{python}: {error}"
    if done.returncode:
        last = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        return None, f"{args.venv}: pose2sim and aniposelib not importable ({last})"
    return python, done.stdout.strip()


def peer_environment() -> dict[str, str]:
    """This environment without what would let the peers import jaxpose's packages; no GPU, no display."""
    environment = {name: value for name, value in os.environ.items() if name not in ("PYTHONPATH", "PYTHONHOME")}
    return {**environment, "JAX_PLATFORMS": "cpu", "MPLBACKEND": "Agg"}


def run_peer(python: pathlib.Path, family: str, methods: list[str], work: pathlib.Path, calibration: pathlib.Path,
             recordings: dict[str, RecordingInput], skeleton: Skeleton, args: PeersArgs, repeats: int = 1,
             limit_s: float | None = None) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, list[float]], str]:  # fmt: skip
    """One driver process for `family`'s `methods` over `recordings` (inputs as detected):
    ({recording: {method: f64[F, J, 3] mm}}, {method: [[wall, CPU] seconds per call]}, "" or what went wrong)."""
    work, calibration = work.resolve(), calibration.resolve()
    work.mkdir(parents=True, exist_ok=True)
    listed = []
    for index, (name, inputs) in enumerate(recordings.items()):
        np.savez(work / f"inputs_{index}.npz", keypoints=inputs.keypoints, confidence=inputs.confidence)
        files = {"inputs": f"inputs_{index}.npz", "output": f"output_{index}.npz", "work": f"trial_{index}"}
        listed.append({"name": name, **{key: str(work / value) for key, value in files.items()}})
    request = {
        "family": family, "methods": methods, "calibration": str(calibration), "fps": args.fps,
        "joint_names": [name.replace("/", "_") for name in skeleton.joint_names], "parents": list(skeleton.parents),
        "threshold": args.threshold, "repeats": repeats, "times": str(work / "times.json"), "recordings": listed,
    }  # fmt: skip
    (work / "request.json").write_text(json.dumps(request))
    problem = ""
    with open(work / "driver.log", "w") as log:
        try:
            done = subprocess.run([str(python), str(DRIVER), str(work / "request.json")], stdout=log, stderr=subprocess.STDOUT,
                                  cwd=work, env=peer_environment(), timeout=limit_s)  # fmt: skip
            if done.returncode:
                lines = (work / "driver.log").read_text().strip().splitlines() or ["(no output)"]
                problem = f"failed (exit {done.returncode}): {lines[-1]}"
        except subprocess.TimeoutExpired:
            problem = f"capped at {limit_s:.0f} s"
    times = json.loads((work / "times.json").read_text()) if (work / "times.json").exists() else {}
    results = {}
    for entry in listed:
        if pathlib.Path(entry["output"]).exists():
            with np.load(entry["output"]) as found:
                results[entry["name"]] = {method: found[method] for method in found.files}
    return results, times, problem


def write_calibration(path: pathlib.Path, names: Sequence[str], cameras: Cameras, image_size: np.ndarray, source: str,
                      overwrite: bool = False) -> pathlib.Path:  # fmt: skip
    """The rig as the peers read it: Anipose / Pose2Sim TOML in metres (an earlier run's replaced with `overwrite`)."""
    fields = {name: getattr(cameras, name) for name in ("K", "R", "t", "dist")}
    fields = {name: None if value is None else np.asarray(value, np.float64) for name, value in fields.items()}
    cameras = Cameras(**fields, distortion_model=cameras.distortion_model)
    rig = RigCalibration(tuple(names), cameras, np.asarray(image_size), source, "mm")
    write_anipose_toml(path, rig, unit="m", overwrite=overwrite)
    return path


def peer_families(args: PeersArgs) -> dict[str, list[str]]:
    families: dict[str, list[str]] = {}
    for item in args.peers:
        family, _, method = item.partition(".")
        if method not in PEER_METHODS.get(family, {}):
            raise SystemExit(f"--peers {item}: expected one of {[f'{f}.{m}' for f, ms in PEER_METHODS.items() for m in ms]}")
        families.setdefault(family, []).append(method)
    return families


# ----------------------------------------------------------------------------------------------
# Accuracy on a rig project


def cut(inputs: RecordingInput, frames: int | None) -> RecordingInput:
    """The recording's first `frames` frames (all where None)."""
    if frames is None:
        return inputs
    target = None if inputs.target3d is None else inputs.target3d[:frames]
    return dataclasses.replace(inputs, frames=inputs.frames[:frames], keypoints=inputs.keypoints[:frames],
                               confidence=inputs.confidence[:frames], target3d=target)  # fmt: skip


def accuracy(args: PeersArgs, lifter: inference.Lifter3D, python: pathlib.Path | None, families: dict[str, list[str]]) -> dict:
    project = load_rig_project(args.data, progress=True)
    dataset = project.validation
    if project.recovered_calibration is not None or dataset.samples.target3d is None:
        raise SystemExit(f"{args.data.root}: the benchmark needs a calibrated project with ground_truth.npz (world mm)")
    if len(np.unique(dataset.samples.rig_index)) != 1:
        rigs = len(np.unique(dataset.samples.rig_index))
        raise SystemExit(f"{args.data.root}: {rigs} rigs among the held-out recordings; the benchmark takes one")
    source = args.data.calibration or find_calibration(args.data.root)
    rig = read_rig_calibration(source).select(project.camera_names, f"cameras of {args.data.root}")
    if rig.image_size is None:
        raise SystemExit(f"{source}: no image sizes, which Pose2Sim needs")
    args.output.mkdir(parents=True, exist_ok=True)
    rigs = dataset.rigs[int(dataset.samples.rig_index[0])]
    calibration = write_calibration(
        args.output / "calibration.toml", project.camera_names, rigs, rig.image_size, str(source), args.overwrite
    )
    skeleton = dataset.skeleton
    agreeing = np.array([name not in args.disagreeing_joints for name in skeleton.joint_names])
    as_detected = list(recording_inputs(dataclasses.replace(dataset, rigs=dataset.rigs.without_distortion())))
    pinhole = list(recording_inputs(dataset))
    conditions = {"as it is": None, **{f"occluded, seed {seed}": seed for seed in args.seeds}}
    found, problems = {}, []
    for condition, seed in conditions.items():
        detected, undistorted = {}, {}
        for index, (raw, inputs) in enumerate(zip(as_detected, pinhole)):
            raw, inputs = cut(raw, args.max_frames), cut(inputs, args.max_frames)
            if seed is not None:
                occlusion = dataclasses.replace(args.occlusion, seed=seed)
                raw, inputs = (occlude(x, occlusion, args.fps, (index,)) for x in (raw, inputs))
            detected[inputs.name], undistorted[inputs.name] = raw, inputs
        results = {
            name: {method: function(lifter, inputs, args.fps) for method, function in JAXPOSE_METHODS.items()}
            for name, inputs in undistorted.items()
        }
        for family, methods in (families.items() if python else ()):
            started = time.perf_counter()
            work = args.output / "work" / condition.replace(" ", "_").replace(",", "") / family
            peer, _, problem = run_peer(python, family, methods, work, calibration, detected, skeleton, args)
            print(f"{condition}: {family} {time.perf_counter() - started:.0f} s {problem}", file=sys.stderr)
            if problem:
                problems.append(f"{condition}, {family}: {problem} (log: {work / 'driver.log'})")
            for name, points in peer.items():
                results[name].update({PEER_METHODS[family][method]: values for method, values in points.items()})
        scores: dict[str, Scores] = {}
        for name, inputs in undistorted.items():
            views = (inputs.confidence > 0).sum(1)
            for method, points in results[name].items():
                scores.setdefault(method, Scores(agreeing)).add(points, inputs.target3d, views, inputs.seen, skeleton.bones)
        truth = np.stack([limb_spread(inputs.target3d, skeleton.bones) for inputs in undistorted.values()])
        found[condition] = {"methods": {method: score.summary() for method, score in scores.items()},
                            "ground_truth_limb_spread_mm": float(np.nanmean(truth)),
                            "instants": int(sum(len(x.frames) for x in undistorted.values()))}  # fmt: skip
    return {"conditions": found, "problems": problems, "recordings": [x.name for x in pinhole], "joints": list(skeleton.joint_names)}


# ----------------------------------------------------------------------------------------------
# Timing on a synthetic rig


def synthetic_recording(args: PeersArgs, cameras: int, joints: Sequence[str]) -> tuple[RecordingInput, SyntheticConfig]:
    """One walking sequence of `--timing-frames` frames seen by `cameras` synthetic cameras through the
    simulated detector (`jaxpose.synthetic`), on the lifter's joints."""
    config = SyntheticConfig(num_views=cameras, fps=args.fps, noise_sigma_scale=args.noise_scale, outlier_rate=args.outlier_rate)
    bones = sample_bone_lengths(stream_rng(config, Stream.BODY))
    motion = sample_motion(stream_rng(config, Stream.MOTION), "walking", bones, args.timing_frames, config)
    rig = make_rig(stream_rng(config, Stream.ROOM), config)
    detections = simulate_detector(stream_rng(config, Stream.DETECTOR), project_points(rig, motion.poses)[0], config)
    try:
        select = [H36M_17.index(name) for name in joints]
    except KeyError as error:
        raise SystemExit(f"--checkpoint {args.checkpoint}: lifts {tuple(joints)}, not the simulator's joints ({error})") from None
    inputs = RecordingInput("synthetic", np.arange(args.timing_frames), rig, detections.keypoints2d[:, :, select],
                            detections.confidence[:, :, select], motion.poses[:, select])  # fmt: skip
    return inputs, config


def timed(function: Callable[[], np.ndarray], repeats: int) -> tuple[list[list[float]], np.ndarray]:
    """[[wall, CPU] seconds] of the first call (JAX's caches cleared) and `repeats` more; the last result."""
    jax.clear_caches()
    times = []
    for _ in range(1 + repeats):
        started = time.perf_counter(), time.process_time()
        result = function()
        times.append([time.perf_counter() - started[0], time.process_time() - started[1]])
    return times, result


def timing(args: PeersArgs, lifter: inference.Lifter3D, python: pathlib.Path | None, families: dict[str, list[str]]) -> dict:
    rows = {}
    for count in args.cameras:
        inputs, config = synthetic_recording(args, count, lifter.joint_names)
        names = [f"cam{c + 1:02d}" for c in range(count)]
        work = args.output / "timing" / f"{count}_cameras"
        work.mkdir(parents=True, exist_ok=True)
        sizes = np.tile(config.image_size, (count, 1))
        calibration = write_calibration(work / "calibration.toml", names, inputs.cameras, sizes, "synthetic", args.overwrite)
        row = {}
        error = lambda points: float(np.nanmean(np.linalg.norm(points - inputs.target3d, axis=-1)))  # noqa: E731
        for method, function in JAXPOSE_METHODS.items():
            times, points = timed(lambda function=function: function(lifter, inputs, args.fps), args.repeats)
            row[method] = {"times": times, "problem": "", "mpjpe_mm": error(points)}
        for family, methods in (families.items() if python else ()):
            groups = [methods] if family == "pose2sim" else [[method] for method in methods]  # filtering reads the triangulation
            for group in groups:
                started = time.perf_counter()
                folder = work / f"{family}_{'_'.join(group)}"
                found, times, problem = run_peer(python, family, group, folder, calibration, {"synthetic": inputs},
                                                 lifter.skeleton, args, 1 + args.repeats, args.peer_limit_s)  # fmt: skip
                print(f"{count} cameras: {family} {group} {time.perf_counter() - started:.0f} s {problem}", file=sys.stderr)
                for method in group:
                    points = found.get("synthetic", {}).get(method)
                    row[PEER_METHODS[family][method]] = {"times": times.get(method, []), "problem": problem,
                                                         "mpjpe_mm": None if points is None else error(points)}  # fmt: skip
        rows[count] = row
    return {"frames": args.timing_frames, "noise_scale": args.noise_scale, "outlier_rate": args.outlier_rate, "cameras": rows}


def run(args: PeersArgs) -> dict:
    unknown = set(args.part) - {"accuracy", "timing"}
    if unknown:
        raise SystemExit(f"--part {sorted(unknown)}: expected accuracy and/or timing")
    check_report(args.output, args.overwrite)
    families = peer_families(args)
    python, peers = peer_python(args) if families else (None, "no peer chosen (--peers)")
    if python is None:
        print(f"peers skipped: {peers}", file=sys.stderr)
    lifter = inference.load(args.checkpoint)
    load = os.getloadavg()
    report = {"setup": (f"{os.cpu_count()} CPU cores (load average {load[0]:.1f} at the start), jax {jax.__version__};"
                        f" peers: {peers if python else 'skipped, ' + peers};"
                        f" lifter {args.checkpoint} (step {lifter.step}).")}  # fmt: skip
    if "accuracy" in args.part:
        report["accuracy"] = accuracy(args, lifter, python, families)
    if "timing" in args.part:
        report["timing"] = timing(args, lifter, python, families)
    report["setup"] += f" Load average {os.getloadavg()[0]:.1f} at the end."
    markdown = report_markdown(report)
    write_report(args.output, report, markdown)
    return report


def main(argv: Sequence[str] | None = None) -> dict:
    args = tyro.cli(PeersArgs, args=argv, description=__doc__.split("\n\n")[0], prog="python -m benchmarks.peers")
    return run(args)


if __name__ == "__main__":
    main()
