"""Your rig, your lifter: train a single-view 3D lifter from your own multi-camera recordings.

    python -m experiments.rig --data.root PROJECT                 # preset cpu: the recipe for 2 CPU cores
    python -m experiments.rig                                     # the embedded example project (written on first use)
    python -m experiments.rig --data.root PROJECT --data.sync auto               # cameras not started together
    python -m experiments.rig --data.root PROJECT --supervision full             # the twin, where ground truth covers training
    python -m experiments.rig --help                                             # every flag

PROJECT holds one folder per recording, each with the detections of every camera (OpenPose JSON
folders, COCO results per camera, or a detections.npz), and optionally a calibration (Anipose /
Pose2Sim / FreeMoCap TOML, EasyMocap intri.yml + extri.yml, or a jaxpose camera file); without one
the rig is recovered from the recordings.  The layout: `jaxpose.rig.project`; every option: `jaxpose.rig.config`
and docs/rig.md ("Train on your own rig").

The lifter is trained on the detector's own joints (root first: its mid-hip, derived from the hips
where the detector has none).  A held-out part (--data.validation-recordings, or the last
--data.validation-fraction of every recording) is evaluated without ground truth (`jaxpose.training.self_consistency`:
how the views' predictions agree), and with it where a recording has a ground_truth.npz.  The run
directory is used by `jaxpose.predict` and `jaxpose.export` like any other.
"""

from __future__ import annotations

import logging

from experiments import cli
from jaxpose.training.experiment import ExperimentConfig, cpu_recipe, paper_preset
from jaxpose.training.run_directory import RECOVERED_CAMERAS_FILE, RECOVERED_SESSIONS_DIR, RunDirectory, RunRecord
from jaxpose.training.splits import Splits
from jaxpose.formats.camera_file import save_cameras
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig, recorded_settings
from jaxpose.rig.split import RigProject

log = logging.getLogger("jaxpose")

EXAMPLE_ROOT = RigProjectConfig().root


def load_splits(data: RigProjectConfig, progress: bool = True) -> Splits:
    """The project's training recordings and its held-out part; the embedded example is written first
    when --data.root is left at its default and does not exist yet.  `progress`: --run.progress.  (Every
    instant is prepared: a temporal lifter's windows need no option of loading.)  The paths are taken absolute
    and resolved."""
    if data.root == EXAMPLE_ROOT and not data.root.exists():
        from jaxpose.synthetic.project import write_rig_project

        log.info("writing the embedded example project to %s", data.root)
        write_rig_project(data.root)
    data = data.resolved()  # one project, one cache entry and one record, however the command line named it
    project = load_rig_project(data, progress=progress)
    artifacts = ()
    # The recovered rigs are the run's assets, where its folder will keep them (the record lists them).
    rigs = RunDirectory.recovered_rig_files([session.name for session in project.sessions])  # none for a calibrated project
    if project.sessions:

        def write_calibration(run: RunDirectory) -> None:
            from jaxpose.calibration.rig_file import world_and_scale, write_recovered_rig  # the calibrate extra, which recovered it

            for session in project.sessions:
                calibration = session.calibration
                json_path = run.path / rigs[session.name]
                toml_path = json_path.with_suffix(".toml")
                json_path.parent.mkdir(exist_ok=True)
                sizes = {"rig": [tuple(int(v) for v in size) for size in calibration.image_size]}
                world, scale = world_and_scale(calibration)
                comment = (f"Recovered by jaxpose.calibrate from the recordings {', '.join(session.recordings)} of {data.root}."
                           f" World frame: {world}; scale: {scale}.")  # fmt: skip
                save_cameras(json_path, {"rig": (list(calibration.camera_names), calibration.cameras)}, sizes, comment)
                write_recovered_rig(toml_path, calibration, overwrite=True)  # the run's own file, rewritten on a resume

        artifacts = (write_calibration,)
    sessions = {session.name: list(session.recordings) for session in project.sessions} if len(project.sessions) > 1 else None
    record = RunRecord(project=recorded_settings(data, project.layout), sessions=sessions, recovered_rigs=rigs)
    return Splits(
        train=project.train,
        test=project.validation,
        group_label="recording",
        camera_names=project.camera_names,
        notes=project_notes(project, data),
        artifacts=artifacts,
        record=record,
    )


def project_notes(project: RigProject, data: RigProjectConfig) -> tuple[str, ...]:
    """The report's account of the data: per recording what loading found and did; the recovered rig."""
    lines = [
        f"**Rig project {data.root}: {len(project.recordings)} recordings, cameras {', '.join(project.camera_names)},"
        f" keypoint layout {project.layout}**",
        "",
        "| Recording | instants | cameras | frame offsets | instants with a choice of person | views without the person | ground-truth instants | calibration |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in project.recordings:
        offsets = ", ".join(f"{camera} {offset:+d}" for camera, offset in r.offsets.items() if offset) or "none"
        if r.offsets_estimated:
            offsets += " (estimated" + ("" if r.sync_reliable else ", UNRELIABLE") + ")"
        lines.append(
            f"| {r.name} | {r.instants} | {len(r.cameras)} | {offsets} | {r.instants_with_choice} | {r.views_without_match}"
            f" | {r.ground_truth_instants} | {r.calibration} |"
        )
    warnings = [f"- {name}: {warning}" for name, warning in [(r.name, w) for r in project.recordings for w in r.warnings]]
    warnings += [f"- {warning}" for warning in project.warnings]
    if warnings:
        lines += ["", "**Warnings of loading** (each also in the log):", "", *warnings]
    notes = ["\n".join(lines)]
    held_out = ", ".join(data.validation_recordings) or f"the last {data.validation_fraction:.0%} of every recording"
    truth = (
        f"Ground truth over the joints {', '.join(project.ground_truth_joints)}."
        if project.ground_truth_joints
        else "No ground truth: the validation is the ground-truth-free table below."
    )
    notes.append(
        f"Training: {len(project.train)} instants; validation ({held_out}): {len(project.validation)} instants. {truth}"
        f" Loading: {project.prepared}."
    )
    if len(project.sessions) == 1:
        from jaxpose.calibrate import report as calibration_report

        notes.append(
            f"No calibration file: the rig was recovered from the recordings and written to {RECOVERED_CAMERAS_FILE}"
            f" in the run directory.\n\n{calibration_report(project.recovered_calibration, None, None)}"
        )
    elif project.sessions:
        notes.append(session_notes(project.sessions))
    return tuple(notes)


FOUND = {"labels": "given by --data.sessions", "data": "found from the data (recordings one rig explains belong together)"}


def session_notes(sessions) -> str:
    """The report's account of a project of several sessions: each session's recordings and rig."""
    from jaxpose.calibrate import report as calibration_report

    lines = [
        f"No calibration file: the recordings come from {len(sessions)} sessions ({FOUND.get(sessions[0].found, sessions[0].found)}),"
        f" each with its own rig recovered from its recordings and written to {RECOVERED_SESSIONS_DIR}/SESSION.json and .toml"
        " in the run directory.",
        "",
        "| Session | recordings | rig re-projection, worst camera's median (px) |",
        "|---|---|---|",
    ]
    lines += [f"| {s.name} | {', '.join(s.recordings)} | {s.reprojection_px:.2f} |" for s in sessions]
    for session in sessions:
        lines += ["", f"Session {session.name}:", "", calibration_report(session.calibration, None, None)]
    return "\n".join(lines)


# Preset "cpu": the Human3.6M cpu recipe (`experiments.h36m`, each choice measured there): a width-512
# lifter of one stage, dropout 0.1, batch 128, cosine schedule, RANSAC pseudo-labels with a pseudo-Huber
# label penalty, the rescaled loss weights.  Inputs augmented by dropping joints (--train.augment.drop
# 0.1): free on detections in docs/robust_input.md (SH 81.1 / 81.5 against 81.1 / 81.3 mm, twin 55.1
# against 55.0), while a missing joint then moves the others by 27 mm instead of 41.  The warm-up is that
# of the development preset (a small project has few steps).
# The budget is 70 epochs, but at most RIG_SAMPLES: on a larger project every epoch is thinned to fit
# (--train.max-samples; the report says so), so that the budget does not grow with the project.
RIG_SAMPLES = 5_000_000
# It is the Human3.6M cpu recipe's time rather than its 5.4M samples (h36m.CPU_SAMPLES): a rig run does
# more besides its steps, measured on the H36M-sized stand-in of benchmarks/rig_budget.py (2 cores):
# dropping joints costs 1.7% per step; a first run prepares and pseudo-labels every instant (~32 s, read
# from the cache on the next); the held-out part is the last 20% of every recording (3.5x Human3.6M's
# test split: ~16 s more of evaluation).  5.4M less those 6-8% is 5.0M; on the learning curve that is
# about 0.1 mm (55 of 70 epochs cost 0.3-0.5 mm on the development split, docs/benchmarks.md), under the
# seed spread.  The periodic evaluation (the ground-truth-free measures, ~0.5 s each) every 2,000 steps:
# ~20 of them over the capped budget, where every 500 steps made 84 (~45 s).
CPU = cpu_recipe(RigProjectConfig(), warmup_steps=150, run_dir="runs/rig", max_samples=RIG_SAMPLES, drop=0.1, eval_every=2000)

# Preset "paper": Sec. IV-A of the paper on your recordings (the authors' network, Adam 1e-3, the
# paper's loss weights, batch 8192): an accelerator's job on a large project.
PAPER = paper_preset(RigProjectConfig(), batch_size=8192, epochs=500, checkpoint_every=250, run_dir="runs/rig_paper")

PRESETS: dict[str, ExperimentConfig] = {"cpu": CPU, "paper": PAPER}
PRESET_NOTES = {
    "cpu": "the cpu recipe, at most Human3.6M's time: ~21 min on 2 CPU cores for a project of its size or larger",
    "paper": "Sec. IV-A of the paper",
}
EXPERIMENT = cli.Experiment(
    name="rig",
    presets=PRESETS,
    preset_notes=PRESET_NOTES,
    load_splits=load_splits,
    loads_with_run_settings=True,
    expected_files=lambda data: (
        f"This run reads the rig project {data.root}: see `python -m experiments.rig --help` and"
        " docs/rig.md for its layout."
    ),
)


def main(argv: list[str] | None = None) -> dict:
    return cli.main(EXPERIMENT, argv, __doc__)


if __name__ == "__main__":
    main()
