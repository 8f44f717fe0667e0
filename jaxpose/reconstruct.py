"""3D motion of a rig project's recordings, in the files biomechanics uses: the triangulation and the
trained lifter fused, no gap where a camera sees the person.

    python -m jaxpose.reconstruct --checkpoint RUN --data.root PROJECT --output DIR --fps 50

RUN is a run of `experiments.rig` on the project (its lifter lifts every camera's view); PROJECT any
project `experiments.rig` reads, with the same --data.* flags (the split flags aside: every instant of
every recording is reconstructed).  The --data defaults are the settings RUN was trained with (its
run.json: `--help` with --checkpoint shows them); a flag given always wins, said in one line where it
differs from the run's.  The world frame is the calibration's; a project without one is
taken in the rig recovered in RUN (RUN/recovered_cameras.json), never recovered again.

Per recording and instant: each camera's detection and lifted pose, fused in one robust weighted least
squares (`jaxpose.reconstruction.fusion`); each joint gets its provenance (triangulated: two or more
views agree; fused: one view, the lifts give the depth; lifted: no view, the lifts alone) and an
uncertainty.  Then each recording's motion is solved over time (`jaxpose.reconstruction.trajectory`:
the instants' evidence with a constant-velocity prior and each limb's length held constant, robustly;
--trajectory.* its settings): an instant no camera sees is bridged by it up to --max-gap frames, with its
uncertainty.  --no-smoothing keeps each instant's own estimate instead, as before: such instants
interpolated up to --max-gap frames, and so is a joint no camera detects for that long
(--no-bridge-lifted keeps its lifts).  A longer gap splits the recording into segments
(`jaxpose.formats.gaps`).  Files per recording in DIR
(`jaxpose.reconstruction.motion_files`): <recording>.trc (OpenSim, Pose2Sim's layout, metres, Y up; a
later segment <recording>.seg<S>.trc; with --c3d a .c3d beside each), <recording>.csv and
<recording>.npz (calibration's world, mm, with provenance, uncertainty and views per joint), and
report.md / report.json, what was done per recording.  docs/reconstruction.md: the workflow, the
measured accuracy, when to trust a lifted-only joint.

No file is written over without --overwrite, all checked before any work; each is written to a
temporary name renamed into place (`jaxpose.formats.outputs`).  One reconstruct at a time writes into DIR
(a second stops at once, naming the first), so its report lists every file there; after Ctrl-C each
recording's files are whole and the report lists them and the recordings not done (exit code 130).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pathlib
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from typing import Annotated, Literal


def _interrupted_while_starting(number, frame):
    print("jaxpose.reconstruct: interrupted (Ctrl-C) while starting: nothing written", file=sys.stderr, flush=True)
    os._exit(128 + number)  # at once: an exception raised inside the imports can be swallowed by them


if __name__ == "__main__" and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    signal.signal(signal.SIGINT, _interrupted_while_starting)  # the imports below take seconds: no traceback from them

import numpy as np
import tyro
from tqdm.auto import tqdm

from jaxpose.serving import inference
from jaxpose.training.checkpoint import CheckpointError
from jaxpose.compilation_cache import enable_compilation_cache
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.outputs import OutputError, check_output_folder, check_report, exclusive_folder, write_report
from jaxpose.logs import show_logs
from jaxpose.reconstruction import motion_files, recording
from jaxpose.reconstruction.fusion import FusionConfig, Provenance
from jaxpose.formats.gaps import DEFAULT_MAX_GAP
from jaxpose.reconstruction.motion_quality import motion_summary
from jaxpose.reconstruction.trajectory import MIN_LENGTH_INSTANTS, TrajectoryConfig, limb_lengths
from jaxpose.rig.config import RigProjectConfig, differences
from jaxpose.training.run_directory import RunDirectory, parse_over_run
from jaxpose.rig.recordings import find_project
from jaxpose.rig.tracked import MIN_TRACK_SCORE

# The fastest rig worth reconstructing (high-speed sport cameras; a detector per frame beyond it is not how
# such footage is read): a larger --fps is a typo or frames numbered in another unit, and its prior would
# allow a body no acceleration over the whole recording (a line through a walk).
MAX_FPS = 10000.0
LOCK_FILE = "reconstruct.lock"
"""Held in --output while a reconstruct writes there (`exclusive_folder`), removed at its end."""
MD_LIMBS = ("elbow", "wrist", "knee", "ankle")
"""report.md's person table shows the limbs ending at these joints (upper arms, forearms, thighs, shanks)."""
INTERRUPTED_EXIT = 128 + signal.SIGINT  # the shell's code for a command ended by Ctrl-C: 130

@dataclasses.dataclass(frozen=True)
class ReconstructArgs:
    """The command's flags."""

    checkpoint: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory of `experiments.rig` on the project (or its checkpoints/); its lifter lifts every view."""
    output: Annotated[pathlib.Path, tyro.conf.arg(metavar="DIR")]
    """Folder for the files of every recording and report.md / report.json (created if absent)."""
    fps: float
    """Frames per second of the recordings (rig projects store none): the files' Time = frame / fps."""
    data: RigProjectConfig = RigProjectConfig()
    """The rig project, as `experiments.rig` reads it (the split flags --data.validation-* and the strides
    do not apply: every instant of every recording is reconstructed)."""
    max_gap: int = DEFAULT_MAX_GAP
    """Up to this many frames in a row where a joint is missing (no camera sees the person) are filled by
    linear interpolation (Pose2Sim's default, 10); a longer gap splits the recording into segments."""
    smoothing: bool = True
    """Solve each recording's motion over time (smooth, limb lengths kept, gaps bridged: --trajectory.*);
    --no-smoothing keeps each instant's own estimate (for fast motion and impacts, docs/reconstruction.md)."""
    trajectory: TrajectoryConfig = TrajectoryConfig()
    """The trajectory's model: process noise, limb-length sigma, robust loss (`jaxpose.reconstruction.trajectory`)."""
    bridge_lifted: bool = True
    """With --no-smoothing: a joint no camera detects for at most --max-gap frames, between frames where
    cameras fix it, is interpolated between them rather than taken from the lifts alone (measured better on
    Human3.6M: docs/reconstruction.md); --no-bridge-lifted keeps the lifts."""
    up_axis: Literal[motion_files.UP_AXES] = "auto"  # type: ignore[valid-type]
    """The calibration's up axis (Human3.6M: +z); the .trc turns it to OpenSim's Y.  auto: the world axis
    the cameras' image up points along on average (refused if none is within 30 degrees); printed and
    stated in every .trc's first line."""
    c3d: bool = False
    """Also write a .c3d beside each .trc (the same markers and axes, in mm): needs ezc3d, pip install
    'jaxpose[reconstruct]'."""
    fusion: FusionConfig = FusionConfig()
    """The fusion's model: its standard deviations and robust loss (`jaxpose.reconstruction.fusion`)."""
    overwrite: bool = False
    """Replace existing files of these recordings and the report in --output; without it the command stops
    before any work."""
    progress: bool = True
    """A progress bar over the recordings."""


def run(args: ReconstructArgs) -> dict:
    """The whole command; returns the report (as report.json holds it)."""
    if not 0 < args.fps < float("inf"):
        raise ValueError(f"--fps must be a positive finite number, got {args.fps}")
    if args.fps > MAX_FPS:
        raise ValueError(f"--fps {args.fps:g}: frames per second of the recordings, at most {MAX_FPS:g} (a typo, or frames numbered in another unit?)")
    if args.max_gap < 0:
        raise ValueError(f"--max-gap must be >= 0 frames, got {args.max_gap}")
    if args.c3d:
        try:
            import ezc3d  # noqa: F401 - missing, refused before any work
        except ImportError:
            raise ImportError("--c3d needs ezc3d: pip install 'jaxpose[reconstruct]' (or pip install ezc3d)") from None
    with _CtrlC() as ctrl_c:
        found = find_project(args.data.root, args.data.recordings, args.data.calibration)
        check_output_folder(args.output, _inputs(args))
        with exclusive_folder(args.output, LOCK_FILE, "--output", "jaxpose.reconstruct"):  # one report per folder
            return _reconstruct(args, found, ctrl_c)


def _reconstruct(args: ReconstructArgs, found, ctrl_c: _CtrlC) -> dict:
    """`run` once the output folder is this process's."""
    earlier = check_outputs(args, found.names)
    run = RunDirectory.of(args.checkpoint)
    lifter = inference.load(run)
    project = recording.load_every_instant(args.data, run, args.progress, found)
    dataset = project.instants
    if tuple(dataset.skeleton.joint_names) != tuple(lifter.joint_names):
        raise ValueError(
            f"the lifter of {lifter.source} lifts the joints {lifter.joint_names}, the project {args.data.root} has"
            f" {dataset.skeleton.joint_names}: reconstruct with a run trained on this project's layout"
        )
    up_axis = args.up_axis
    if up_axis == "auto":
        up_axis = motion_files.camera_up_axis(dataset.rigs)
        print(f"up axis {up_axis}, from the cameras (--up-axis to name it)", file=sys.stderr)
    rows, files = [], []
    names = [loaded.name for loaded in project.recordings]
    instants_of = {loaded.name: loaded.instants for loaded in project.recordings}
    for loaded in project.recordings:
        dropped = f"; {loaded.implausible_tracks} tracks the detector scored low left out" if loaded.implausible_tracks else ""
        print(f"recording {loaded.name}: {_people(len(loaded.people))} found{dropped}", file=sys.stderr)
    try:
        bar = tqdm(recording.recording_inputs(dataset), total=len(project.recordings), desc="recordings", unit="recording",
                   disable=not args.progress)  # fmt: skip
        for inputs in bar:
            ctrl_c.check()
            bar.set_postfix_str(inputs.name)
            if not inputs.seen.any():  # nothing to fuse or lift: said, listed, and the other recordings go on
                print(f"recording {inputs.name}: no camera detects the person at any instant (scores below --data.min-confidence"
                      f" {args.data.min_confidence:g}, or no detection): no file written", file=sys.stderr)  # fmt: skip
                rows.append({"recording": inputs.name, "person": inputs.person, "frames": len(inputs.frames), "skipped": "no detection", "files": []})
                continue
            trajectory = args.trajectory if args.smoothing else None
            motion, _ = recording.lift_and_reconstruct(
                lifter, inputs, args.fusion, args.max_gap, args.bridge_lifted, trajectory=trajectory, fps=args.fps
            )
            quality = motion_summary(motion.points, lifter.skeleton.bones, lifter.joint_names, inputs.target3d)
            held = _limbs_held(motion, lifter.skeleton.bones, lifter.joint_names) if args.smoothing else {}
            if held and not held["limbs_held"]:
                print(f"recording {inputs.name}: no limb measured at {MIN_LENGTH_INSTANTS} instants ({len(inputs.frames)} frames):"
                      " smoothed without limb lengths, as the report says", file=sys.stderr)  # fmt: skip
            with ctrl_c.deferred():  # a recording's files are all written and listed, or none of them
                written = motion_files.write_motion(args.output, motion, lifter.joint_names, args.fps, up_axis, args.c3d)
                files += [str(path) for path in written]
                person = person_summary(motion, inputs, instants_of.get(inputs.recording, len(inputs.frames)), lifter.skeleton.bones, lifter.joint_names)
                rows.append(recording_summary(motion, lifter.joint_names) | person | quality | held | {"files": [path.name for path in written]})
        interrupted = None
    except KeyboardInterrupt:
        done = {row.get("of_recording", row["recording"]) for row in rows}
        interrupted = {"after": len(rows), "of": len(names), "not_reconstructed": [name for name in names if name not in done]}
    left = sorted(str(path) for path in set(earlier) - {pathlib.Path(file) for file in files})
    if left and interrupted is None:  # as jaxpose.predict does: an earlier run's segments that this run has not
        print(f"files of an earlier run not written now, left as they were: {', '.join(left)}", file=sys.stderr)
    report = {
        "checkpoint": str(args.checkpoint),
        "project": str(args.data.root),
        "calibration": project.recordings[0].calibration if project.recordings else "",
        "fps": args.fps,
        "max_gap": args.max_gap,
        "bridge_lifted": args.bridge_lifted,
        "smoothing": args.smoothing,
        "trajectory": dataclasses.asdict(args.trajectory) if args.smoothing else None,
        "min_length_instants": MIN_LENGTH_INSTANTS if args.smoothing else None,
        "up_axis": up_axis,
        "trc_axes": motion_files.rotation_note(motion_files.opensim_rotation(up_axis), up_axis),
        "joint_names": list(lifter.joint_names),
        "fusion": dataclasses.asdict(args.fusion),
        "people": {loaded.name: {"found": len(loaded.people), "instants": list(loaded.people), "tracks_left_out": loaded.implausible_tracks,
                                 "person_instants_left_out": loaded.dropped_person_instants} for loaded in project.recordings},
        "min_track_score": MIN_TRACK_SCORE,
        "recordings": rows,
        "earlier_files_left": left,
        "interrupted": interrupted,
    }
    write_report(args.output, report, report_markdown(report), echo=interrupted is None)
    if interrupted is not None:
        raise Interrupted(f"{interrupted['after']} of {interrupted['of']} recordings written (each whole), listed in {args.output / 'report.md'}")
    return report


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, once the report of what was written is: the message says what is there."""


class _CtrlC:
    """Ctrl-C (SIGINT) in the main thread while the command runs: a KeyboardInterrupt where it is pressed, except
    inside `deferred` (at its end then); and remembered, so that one Python drops (raised inside a garbage
    collector's callback, as JAX's) still ends the work at the next `check`.  Elsewhere (another thread, SIGINT
    ignored or the caller's own handler) nothing is changed."""

    def __init__(self):
        self.pressed = self.deferring = self.installed = False

    def _handler(self, number, frame) -> None:
        self.pressed = True
        if not self.deferring:
            raise KeyboardInterrupt

    def __enter__(self) -> _CtrlC:
        if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, self._handler)
            self.installed = True
        return self

    def __exit__(self, *exception) -> None:
        if self.installed:
            signal.signal(signal.SIGINT, signal.default_int_handler)

    def check(self) -> None:
        if self.pressed:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        self.deferring = True
        try:
            yield
        finally:
            self.deferring = False
        self.check()


def _limbs_held(motion: recording.RecordingMotion, bones: Sequence[tuple[int, int]], joint_names: Sequence[str]) -> dict:
    """Which limbs the trajectory held at a constant length: those measured at `MIN_LENGTH_INSTANTS` instants or
    more (`limb_lengths` of the recording's evidence, as `smooth_recording` takes them); the others were free."""
    lengths = limb_lengths(motion.fusion.points, motion.fusion.provenance, bones)
    free = [f"{joint_names[parent]}-{joint_names[child]}" for (child, parent), length in zip(bones, lengths) if not np.isfinite(length)]
    return {"limbs_held": int(np.isfinite(lengths).sum()), "limbs_free": free}


def parse(argv: Sequence[str] | None) -> ReconstructArgs:
    """The command line over the run's settings: the project settings the run named by --checkpoint was trained
    with (its run.json) are the --data defaults, so `--help` shows them and every flag given wins; a flag given
    that differs from the run's value is said in one line.  Paths are taken absolute and resolved."""
    args, run, record = parse_over_run(
        ReconstructArgs, argv, lambda record: {"data": (record and record.project) or RigProjectConfig()}, __doc__, "python -m jaxpose.reconstruct"
    )  # fmt: skip
    args = dataclasses.replace(args, data=args.data.resolved())
    trained = None if record is None else record.project
    if trained is None:
        print(f"{run.path} records no project settings (a run from before run.json): the --data flags as given", file=sys.stderr)
    else:
        for line in differences(args.data, trained):
            print(line, file=sys.stderr)
    return dataclasses.replace(args, data=_session_recordings(args, run, record))


def _session_recordings(args: ReconstructArgs, run: RunDirectory, record) -> RigProjectConfig:
    """--data with the recordings limited to the session whose recovered rig --data.calibration names (the
    run's recovered_sessions/SESSION.toml is that session's world, no other's); a recording of another session
    named by --data.recordings is refused."""
    session = None if args.data.calibration is None else run.session_of(args.data.calibration)
    if session is None or record is None or not record.sessions or session not in record.sessions:
        return args.data
    own = tuple(record.sessions[session])
    others = [name for name in args.data.recordings if name not in own]
    if others:
        raise SystemExit(
            f"jaxpose.reconstruct: error: --data.calibration {args.data.calibration} is the rig of session {session}"
            f" (recordings {', '.join(own)}), not of {', '.join(others)}: name that session's rig for them"
        )
    if not args.data.recordings:
        print(f"--data.calibration {args.data.calibration}: the rig of session {session}: its recordings only ({', '.join(own)})", file=sys.stderr)
    return dataclasses.replace(args.data, recordings=args.data.recordings or own)


def _inputs(args: ReconstructArgs) -> list[pathlib.Path]:
    return [args.data.root, args.checkpoint, *([args.data.calibration] if args.data.calibration else [])]


def check_outputs(args: ReconstructArgs, names: Sequence[str]) -> list[pathlib.Path]:
    """Refuse, before any work, to write over an earlier run's files without --overwrite; returns them
    (with --overwrite, those this run does not write again are named after it, and left as they were)."""
    colliding = motion_files.colliding_names(names)
    if colliding:
        first, second = colliding
        raise OutputError(
            f"recordings {first!r} and {second!r}: a later segment or a person of {first!r} is written as {second}.trc, the file of"
            f" {second!r}; reconstruct them into separate --output folders (--data.recordings {first} / {second})"
        )
    check_report(args.output, args.overwrite)
    earlier = [path for name in names for path in motion_files.existing_outputs(args.output, name)]
    if earlier and not args.overwrite:
        listed = ", ".join(path.name for path in earlier[:4]) + (f" and {len(earlier) - 4} more" if len(earlier) > 4 else "")
        raise OutputError(f"--output {args.output}: holds {listed} of these recordings; pass --overwrite to replace them")
    return earlier


def _people(count: int) -> str:
    return "1 person" if count == 1 else f"{count} people"


def person_summary(motion: recording.RecordingMotion, inputs: recording.RecordingInput, instants: int,
                   bones: Sequence[tuple[int, int]], joint_names: Sequence[str]) -> dict:
    """One person's place in their recording for the report: the recording, the person k, their first and last
    frame, their coverage (the share of the recording's `instants` at which a camera sees them) and each limb's
    median length over the motion (mm, "parent-child", null where never measured)."""
    lengths = np.linalg.norm(motion.points[:, [child for child, _ in bones]] - motion.points[:, [parent for _, parent in bones]], axis=-1)
    finite = np.isfinite(lengths)
    median = [float(np.median(lengths[finite[:, b], b])) if finite[:, b].any() else None for b in range(len(bones))]
    return {
        "of_recording": inputs.recording or motion.name,
        "person": inputs.person,
        "last_frame": int(motion.frames[-1]),
        "coverage": round(float(motion.seen.sum()) / max(instants, 1), 4),
        "limb_length_mm": {f"{joint_names[parent]}-{joint_names[child]}": None if value is None else round(value, 1)
                           for (child, parent), value in zip(bones, median)},
    }  # fmt: skip


def recording_summary(motion: recording.RecordingMotion, joint_names: Sequence[str]) -> dict:
    """One recording's counts for the report; with the trajectory its motion prior (mm/s^2 per joint, null
    where not solved) and its impacts (accelerations the Student-t prior weighted below 0.5)."""
    cells = np.bincount(motion.provenance.ravel(), minlength=len(Provenance))
    smoothed = {}
    if motion.acceleration_mm_s2 is not None:
        smoothed = {
            "motion_prior_mm_s2": {name: None if np.isnan(value) else round(float(value), 1)
                                   for name, value in zip(joint_names, motion.acceleration_mm_s2)},
            "impacts": int((motion.impact_weight < 0.5).sum()),
        }  # fmt: skip
    return {
        "recording": motion.name,
        "frames": len(motion.frames),
        "first_frame": int(motion.frames[0]),
        "instants_seen": int(motion.seen.sum()),
        "joints_by_provenance": {name: int(count) for name, count in zip(motion_files.PROVENANCE_NAMES, cells)},
        "interpolated_frames": motion.interpolated_frames,
        "segments": len(motion.segments),
        "dropped_frames": motion.dropped_frames,
    } | smoothed


def report_markdown(report: dict) -> str:
    """report.md: the settings and a table of the recordings."""
    names = ("triangulated", "fused", "lifted", "interpolated", "none")
    lines = [
        "# Reconstruction",
        "",
        f"Lifter {report['checkpoint']}; project {report['project']} in the world of {report['calibration']};"
        f" {report['fps']:g} fps; gaps up to {report['max_gap']} frames interpolated; .trc axes {report['trc_axes']}.",
        "",
        "Joints (cells of frame x joint) by provenance: triangulated (2+ views agree), fused (1 view, the lifts"
        " give the depth), lifted (no view: the lifts alone), interpolated (a gap up to --max-gap), none (missing:"
        " outside every segment).",
        "",
        "| recording | frames | instants seen | " + " | ".join(names) + " | interpolated frames | segments | dropped frames |",
        "|---" * (6 + len(names)) + "|",
    ]
    for row in report["recordings"]:
        if "skipped" in row:
            lines.append(f"| {row['recording']} | {row['frames']} | 0 | skipped: {row['skipped']} |" + " |" * (len(names) + 2))
            continue
        counts = " | ".join(str(row["joints_by_provenance"][name]) for name in names)
        lines.append(
            f"| {row['recording']} | {row['frames']} | {row['instants_seen']} | {counts} | {row['interpolated_frames']}"
            f" | {row['segments']} | {row['dropped_frames']} |"
        )
    people = report.get("people", {})
    lines += [
        "",
        "People: per recording, the people found (tracked over time; a track whose detections' keypoints score below"
        f" {report.get('min_track_score', '-')} in the median is left out as no person), and each person's files: its first"
        " and last frame, its coverage (the share of the recording's instants at which a camera sees it) and its limbs'"
        " median lengths (mm: the arms' and legs' here, report.json has every limb's).",
        "",
        "| recording | people found | tracks left out |",
        "|---|---|---|",
        *(f"| {name} | {entry['found']} | {entry['tracks_left_out']} |" for name, entry in people.items()),
        "",
        "| files | recording | person | first frame | last frame | coverage | limb lengths (mm, median) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in (row for row in report["recordings"] if "skipped" not in row):
        limbs = [f"{name} {value:.0f}" for name, value in row["limb_length_mm"].items()
                 if value is not None and any(part in name.split("-")[-1].lower() for part in MD_LIMBS)]  # fmt: skip
        lines.append(f"| {row['recording']} | {row['of_recording']} | {row['person']} | {row['first_frame']} | {row['last_frame']}"
                     f" | {row['coverage']:.1%} | {', '.join(limbs) or '-'} |")  # fmt: skip
    if report["smoothing"]:
        smoothing = (
            "solved over time (the trajectory), each limb held at its median length where both its joints are measured at"
            f" {report['min_length_instants']} instants or more and free otherwise (limbs held)"
        )
    else:
        smoothing = "each instant alone (--no-smoothing)"
    columns = ["recording", *(["limbs held"] if report["smoothing"] else []), "mean acceleration", "mean limb length std",
               "largest limb length std", "acceleration error",
               *(["process noise, median (range)", "impacts"] if report["smoothing"] else [])]  # fmt: skip
    lines += [
        "",
        f"The motion, {smoothing}: its mean acceleration (mm/frame^2), each limb's length spread over time (std, mm;"
        " report.json has every limb's) and, with ground truth, the acceleration error (mm/frame^2); with the"
        " trajectory, the process noise of its motion prior over the joints (mm/s^2, median (range); report.json"
        " has every joint's) and its impacts (accelerations the heavy-tailed prior let through: weight below 0.5).",
        "",
        "| " + " | ".join(columns) + " |",
        "|---" * len(columns) + "|",
    ]
    for row in (row for row in report["recordings"] if "skipped" not in row):
        spreads = {name: value for name, value in row["limb_length_std_mm"].items() if value is not None}
        largest = max(spreads, key=spreads.get) if spreads else None
        cells = [
            _number(row["mean_acceleration_mm_per_frame2"], 2), _number(row["mean_limb_length_std_mm"], 1),
            f"{spreads[largest]:.1f} ({largest})" if spreads else "-", _number(row.get("acceleration_error_mm_per_frame2"), 2),
        ]  # fmt: skip
        if report["smoothing"]:
            count = row["limbs_held"] + len(row["limbs_free"])
            none = f" (no limb measured at {report['min_length_instants']} instants: smoothed without limb lengths)"
            cells.insert(0, f"{row['limbs_held']} of {count}" + ("" if row["limbs_held"] else none))
            cells += [_noise(row.get("motion_prior_mm_s2")), str(row["impacts"]) if "impacts" in row else "-"]
        lines.append(f"| {row['recording']} | " + " | ".join(cells) + " |")
    interrupted = report.get("interrupted")
    if interrupted:
        lines += [
            "",
            f"**Interrupted (Ctrl-C)** after {interrupted['after']} of {interrupted['of']} recordings; not reconstructed:"
            f" {', '.join(interrupted['not_reconstructed']) or '-'}.  Written, each file complete:"
            f" {', '.join(name for row in report['recordings'] for name in row['files']) or 'nothing'}.",
        ]
    return "\n".join(lines) + "\n"


def _noise(per_joint: dict | None) -> str:
    values = [value for value in (per_joint or {}).values() if value is not None]
    return f"{np.median(values):.0f} ({min(values):.0f}-{max(values):.0f})" if values else "-"


def _number(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main(argv: Sequence[str] | None = None) -> dict:
    """Entry point; data, checkpoint and output errors end the process with a one-line message."""
    args = parse(argv)
    show_logs()
    enable_compilation_cache()  # the lifter's programs from disk on the next run
    try:
        return run(args)
    except (ValueError, FileNotFoundError, ImportError, CheckpointError, DataFormatError) as error:
        raise SystemExit(f"jaxpose.reconstruct: error: {error}") from None
    except Interrupted as stop:
        print(f"jaxpose.reconstruct: interrupted (Ctrl-C): {stop}", file=sys.stderr)
        raise SystemExit(INTERRUPTED_EXIT) from None
    except KeyboardInterrupt:
        print(f"jaxpose.reconstruct: interrupted (Ctrl-C) before any recording was written: nothing written to --output {args.output}", file=sys.stderr)
        raise SystemExit(INTERRUPTED_EXIT) from None


if __name__ == "__main__":
    if signal.getsignal(signal.SIGINT) is _interrupted_while_starting:
        signal.signal(signal.SIGINT, signal.default_int_handler)  # started: main reports a Ctrl-C
    main()
