"""A hostile or careless user's folders (issue 42): nothing read from a user's folder runs code, no command
deletes or writes what it was not asked to, and what it refuses is still there afterwards.

Each case failed before its fix.  Issue 42's cases, and where each is tested here:

| Case | Tests |
|---|---|
| 1 --run.overwrite deletes any folder | test_a_run_folder_that_holds_other_files_is_refused_and_left_as_it_was, test_overwrite_removes_only_what_a_run_wrote, test_a_run_folder_from_before_the_record_is_still_a_run |
| 2 predict writes into its input | test_predict_never_writes_into_its_input_folder, test_no_command_touches_a_path_outside_its_named_outputs |
| 3 reconstruct's names collide | test_reconstruct_refuses_recordings_whose_files_would_collide, test_reconstruct_never_writes_into_its_inputs |
| 4 a pickle in the cache runs code | test_a_crafted_pickle_in_the_cache_runs_no_code, test_no_module_unpickles_except_the_named_videopose3d_files, test_a_recovered_rig_is_cached_as_json_and_read_back_whole, test_a_damaged_recovered_rig_is_prepared_again |
| 5 a broken model rewarded | test_a_diverging_run_stops_with_a_message_and_no_nonfinite_checkpoint, test_a_broken_lifter_scores_worse_than_the_truth_on_every_measure |
| 6 one far-off keypoint | test_a_point_the_lens_cannot_undistort_is_nan_and_the_others_match_opencv, test_one_far_off_keypoint_is_undetected_and_the_project_loads |
| 7 BODY_25B read as BODY_25 | test_body25_and_body25b_are_told_apart_by_their_joint_8 |
| 8 reconstruct ignores the run's settings | test_the_run_record_carries_the_project_settings_to_the_commands_that_use_the_run, test_a_recording_no_camera_detects_is_said_and_skipped, test_a_stray_frame_number_is_refused_naming_its_file |
| 9 tracebacks | test_numbers_no_run_can_take_are_one_line_before_anything_is_written, test_a_full_disk_a_read_only_folder_and_a_device_are_one_line_each, test_coco_and_npz_frame_numbers_are_checked_too, test_a_stray_frame_number_is_refused_naming_its_file |
| 10 --fps inf, a TRC name with a tab | test_smaller_cases_of_issue_42 |
| 10 "choose at most 0" | test_no_training_sample_left_says_why |
| 10 "leaving out N training samples" | test_leaving_out_training_samples_names_their_recordings |
| 10 a camera at half the frame rate | test_a_camera_at_half_the_frame_rate_is_named_by_sync |
| 10 an offset of 100,000, limbs of 22 m | test_what_loading_finds_suspect_is_in_the_report |
| 10 "(770 steps)" despite --train.max-steps | test_the_training_line_says_where_max_steps_stops_it |
| 10 the shared compilation cache | test_a_compilation_cache_written_without_a_size_limit_fails_no_later_write, test_a_compilation_cache_that_cannot_take_a_program_is_one_line_not_one_per_compilation |

Issue 52's cases here:

| Case | Tests |
|---|---|
| 5 the C3D first frame wraps at 65536 | test_a_c3d_first_frame_past_16_bits_is_not_wrapped |
| 8 two reconstructs into one --output lose a report | test_two_reconstructs_into_one_output_keep_its_report_whole |
| 11 a session's recording lacks a camera | test_a_session_whose_recording_lacks_a_camera_is_named_with_the_way_out |
| 11 a typo in --data.sessions | test_a_session_naming_a_recording_the_project_lacks_is_refused_with_the_closest_name |
| 11 under 10 frames: no limb constraint | test_a_recording_too_short_for_limb_lengths_is_reported_as_smoothed_without_them |
| 11 Ctrl-C during reconstruct | test_ctrl_c_during_reconstruct_is_one_line_and_a_report_of_what_was_written |
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import json
import os
import pathlib
import pickle
import re
import shutil

import numpy as np
import paths
import pytest

from jaxpose.calibration import Calibration
from jaxpose.calibration.lens import LensEstimate
from jaxpose.calibration.scale import MetricScale
from jaxpose.camera import Cameras
from jaxpose.rig import cache
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project

TINY = ExampleProjectConfig(recordings=1, frames_per_recording=40)


class _Payload:
    """Unpickling this creates `marker`: what a crafted file on a shared drive would do."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _calibration() -> Calibration:
    rng = np.random.default_rng(0)
    cameras = Cameras(K=rng.normal(size=(3, 3, 3)), R=rng.normal(size=(3, 3, 3)), t=rng.normal(size=(3, 3)), dist=rng.normal(size=(3, 5)))
    scale = MetricScale(mm_per_unit=1.5, measured_mm={"thigh": 420.0}, prior_mm={"thigh": 410.0})
    return Calibration(
        cameras=cameras, camera_names=("a", "b", "c"), image_size=np.array([[1920, 1080]] * 3), reprojection_median_px=rng.random(3),
        reprojection_p90_px=rng.random(3), inlier_fraction=rng.random(3), scale=scale, focal_estimated=True, frames_used=120, seconds=2.5,
        lens=LensEstimate(value=rng.random((3, 7)), sigma=rng.random((3, 7)), prior_mean=rng.random((3, 7)), prior_sigma=rng.random((3, 7)),
                          state=np.array([["held", "estimated", "prior", "held", "held", "held", "held"]] * 3)),
        residual_scale=1.02,
    )  # fmt: skip


def _assert_same(a, b):
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b)
        for field in dataclasses.fields(a):
            _assert_same(getattr(a, field.name), getattr(b, field.name))
    elif isinstance(a, (np.ndarray, np.generic)):
        np.testing.assert_array_equal(a, b)
        assert np.asarray(a).dtype == np.asarray(b).dtype
    else:
        assert a == b and type(a) is type(b)


def test_a_recovered_rig_is_cached_as_json_and_read_back_whole(tmp_path):
    temporary = tmp_path / "prepared-x.tmp-1"
    temporary.mkdir()
    folder = cache.commit(temporary, "x", {"meta": 1}, _calibration())
    assert sorted(p.name for p in folder.iterdir()) == ["project.json", cache.RECOVERED_JSON]
    meta, recovered = cache.read_meta(folder, Calibration)
    assert meta == {"meta": 1}
    _assert_same(_calibration(), recovered)


def test_a_crafted_pickle_in_the_cache_runs_no_code(tmp_path):
    """The reproduction of issue 42 case 4: a pickle placed in PROJECT/.jaxpose_cache/prepared-*/ (where
    the recovered rig used to be pickled) is never opened by the next load; the project loads as before."""
    root = write_rig_project(tmp_path / "project", TINY)
    config = RigProjectConfig(root=root)
    first = load_rig_project(config, progress=False)
    (prepared,) = (root / ".jaxpose_cache").glob(f"{cache.PREFIX}*")
    marker = tmp_path / "code-ran"
    for name in ("recovered.pickle", "project.pickle"):
        (prepared / name).write_bytes(pickle.dumps(_Payload(str(marker))))
    (prepared / "train.evil.npy").write_bytes(pickle.dumps(_Payload(str(marker))))  # an object array's way in
    again = load_rig_project(config, progress=False)
    assert not marker.exists()
    np.testing.assert_array_equal(np.asarray(first.train.samples.keypoints2d), np.asarray(again.train.samples.keypoints2d))


def test_a_damaged_recovered_rig_is_prepared_again(tmp_path):
    temporary = tmp_path / "prepared-x.tmp-1"
    temporary.mkdir()
    folder = cache.commit(temporary, "x", {}, _calibration())
    (folder / cache.RECOVERED_JSON).write_text('{"cameras": {"K": {"ndarray": [1], "dtype": "|O"}}}')
    with pytest.raises(ValueError, match=cache.RECOVERED_JSON):
        cache.read_meta(folder, Calibration)


def _calls(tree: ast.AST) -> list[tuple[str, ast.Call]]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            found.append((name, node))
    return found


def test_no_module_unpickles_except_the_named_videopose3d_files():
    """`pickle.load(s)` appears nowhere; `allow_pickle=True` only in `formats.files.load_npz_object`,
    which only the VideoPose3D reader calls (files from the data set folder named on the command line)."""
    unpickling, object_loads = [], []
    for path in sorted((paths.REPO / "jaxpose").rglob("*.py")):
        tree = ast.parse(path.read_text())
        for name, call in _calls(tree):
            if name in ("load", "loads", "Unpickler") and isinstance(call.func, ast.Attribute) and getattr(call.func.value, "id", "") == "pickle":
                unpickling.append(f"{path.name}:{call.lineno}")
            if any(k.arg == "allow_pickle" and not (isinstance(k.value, ast.Constant) and k.value.value is False) for k in call.keywords):
                object_loads.append(path.relative_to(paths.REPO).as_posix())
            if name == "load_npz_object":
                object_loads.append(f"caller {path.relative_to(paths.REPO).as_posix()}")
    assert unpickling == []
    assert sorted(set(object_loads)) == ["caller jaxpose/datasets/videopose3d.py", "jaxpose/formats/files.py"]



def _snapshot(folder) -> dict[str, bytes]:
    """Every file below `folder` with its bytes (the cache aside)."""
    return {
        str(path.relative_to(folder)): path.read_bytes()
        for path in sorted(folder.rglob("*")) if path.is_file() and ".jaxpose_cache" not in path.parts
    }  # fmt: skip


def _never_loads(_data):
    raise AssertionError("the data were loaded before the run folder was checked")


def _experiment(run_dir, overwrite: bool):
    from jaxpose.training.experiment import ExperimentConfig, RunConfig

    return ExperimentConfig(data=None, run=RunConfig(run_dir=run_dir, overwrite=overwrite, progress=False))


@pytest.mark.parametrize("overwrite", [False, True])
@pytest.mark.parametrize("target", ["folder of other files", "the project itself"])
def test_a_run_folder_that_holds_other_files_is_refused_and_left_as_it_was(tmp_path, overwrite, target):
    """Issue 42 case 1: --run.run-dir at a folder holding a project and a thesis (or at the project), with
    or without --run.overwrite: one line naming the folder and what it holds; not a byte changed."""
    from jaxpose.training.runner import run

    folder = tmp_path / "work"
    project = write_rig_project(folder / "project", TINY)
    (folder / "thesis.pdf").write_bytes(b"%PDF-1.7 years of work")
    run_dir = folder if target == "folder of other files" else project
    before = _snapshot(folder)
    with pytest.raises(SystemExit, match=rf"--run.run-dir {run_dir}: holds \d+ entr(y|ies) that no jaxpose run wrote \(.*\); a run folder holds only a run"):
        run(_experiment(run_dir, overwrite), _never_loads)
    assert _snapshot(folder) == before


def test_overwrite_removes_only_what_a_run_wrote(tmp_path):
    """A run folder with a nested run: --run.overwrite removes the run's own entries and keeps the nested run.
    Issue 52: a study's summary is never written into a run folder (the study has a folder of its own), and a
    run folder holding one is refused as holding what no run wrote."""
    from jaxpose.training.run_directory import RunDirectory, prepare_run_dir, write_study_file

    run_dir = tmp_path / "run"
    files = RunDirectory(run_dir)
    prepare_run_dir(_experiment(run_dir, overwrite=False))
    files.metrics.write_text("{}\n")
    (files.checkpoints / "100").mkdir(parents=True)
    files.report_md.write_text("old")
    with pytest.raises(SystemExit, match=r"run: is a run folder, which holds only its run; give the study a folder of its own"):
        write_study_file(run_dir, "search.md", "summary")
    prepare_run_dir(_experiment(run_dir / "supervised", overwrite=False))
    prepare_run_dir(_experiment(run_dir, overwrite=True))
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.json", "plots", "run.json", "supervised"]
    assert (run_dir / "supervised" / "run.json").is_file()
    (run_dir / "search.md").write_text("summary")  # written beside the run by hand: not the run's
    with pytest.raises(SystemExit, match=r"holds 1 entry that no jaxpose run wrote \(search.md\)"):
        prepare_run_dir(_experiment(run_dir, overwrite=True))
    study = write_study_file(tmp_path / "study", "search.md", "summary")  # a study's own folder, with its runs inside
    prepare_run_dir(_experiment(tmp_path / "study" / "row", overwrite=False))
    assert study.read_text() == "summary" and write_study_file(tmp_path / "study", "search.md", "again").read_text() == "again"


def test_a_run_folder_from_before_the_record_is_still_a_run(tmp_path):
    from jaxpose.training.run_directory import check_run_folder

    run_dir = tmp_path / "old_run"
    (run_dir / "checkpoints" / "500").mkdir(parents=True)
    (run_dir / "config.json").write_text("{}")
    (run_dir / "metrics.jsonl").write_text("")
    check_run_folder(run_dir)  # no refusal
    (run_dir / "notes.txt").write_text("mine")
    with pytest.raises(SystemExit, match=r"holds 1 entry that no jaxpose run wrote \(notes.txt\)"):
        check_run_folder(run_dir)


def _refused(main, argv: list[str], match: str) -> None:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    message = str(stop.value.code)
    assert "\n" not in message and "Traceback" not in message, message
    assert re.search(match, message), message


@pytest.fixture(scope="module")
def small_project(tmp_path_factory):
    return write_rig_project(tmp_path_factory.mktemp("hostile") / "project", ExampleProjectConfig(recordings=2, frames_per_recording=20))


def _copy_project(project, to):
    """A copy of `project` to break, without its cache."""
    shutil.copytree(project, to, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    return to


def _set_scores(frames, score: float) -> None:
    """Every keypoint of every person in these OpenPose frame files given the detector score `score`."""
    for frame in frames:
        content = json.loads(frame.read_text())
        for person in content["people"]:
            person["pose_keypoints_2d"][2::3] = [score] * (len(person["pose_keypoints_2d"]) // 3)
        frame.write_text(json.dumps(content))


@pytest.mark.parametrize(
    "outputs",
    [
        lambda folder: ["--output", str(next(folder.glob("*.json"))), "--overwrite"],  # a frame, replaced
        lambda folder: ["--output", str(folder / "poses.json")],  # a stray file among the frames
        lambda folder: ["--output", str(folder.parent / "poses.json"), "--plot", str(folder)],  # PNGs among the frames
        lambda folder: ["--output", str(folder.parent / "poses.json"), "--plot", str(folder / "plots")],
    ],
    ids=["over a frame", "among the frames", "plots among the frames", "plots in a folder inside"],
)
def test_predict_never_writes_into_its_input_folder(small_project, tmp_path, outputs):
    """Issue 42 case 2: --output or --plot inside the OpenPose folder given as --input is refused in one
    line, with or without --overwrite, and the folder is byte-identical afterwards."""
    from jaxpose import predict

    folder = next(small_project.glob("*/cam01_json"))
    before = _snapshot(small_project)
    _refused(predict.main, ["--checkpoint", str(tmp_path / "run"), "--input", str(folder), *outputs(folder)], r"input folder|command's input")
    assert _snapshot(small_project) == before


def test_reconstruct_refuses_recordings_whose_files_would_collide(small_project, tmp_path):
    """Issue 42 case 3: `walking01`'s second segment and the recording `walking01.seg1` would both write
    walking01.seg1.trc: refused before any work, naming both, with the way out."""
    from jaxpose import reconstruct

    project = _copy_project(small_project, tmp_path / "project")
    first, second = sorted(p for p in project.iterdir() if p.is_dir())
    first.rename(project / "trial")
    second.rename(project / "trial.seg1")
    before = _snapshot(project)
    _refused(
        reconstruct.main, ["--checkpoint", str(tmp_path / "run"), "--data.root", str(project), "--output", str(tmp_path / "motion"), "--fps", "50"],
        r"recordings 'trial' and 'trial.seg1'.*separate --output folders",
    )
    assert _snapshot(project) == before and not (tmp_path / "motion").exists()


@pytest.mark.parametrize("inside", ["project", "run"])
def test_reconstruct_never_writes_into_its_inputs(small_project, tmp_path, inside):
    from jaxpose import reconstruct

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")
    output = (small_project if inside == "project" else run) / "motion"
    before = _snapshot(small_project) | _snapshot(run)
    _refused(
        reconstruct.main, ["--checkpoint", str(run), "--data.root", str(small_project), "--output", str(output), "--fps", "50"],
        r"--output .*motion: is inside this command's input folder",
    )
    assert _snapshot(small_project) | _snapshot(run) == before and not output.exists()


def test_the_run_record_carries_the_project_settings_to_the_commands_that_use_the_run(tmp_path, capsys):
    """Issue 42 case 8 / issue 41's run record: a run trained with --data.sync auto, offsets, a calibration in
    metres and a score threshold of 0.2 is read back so by reconstruct (its --data defaults), and export takes
    its threshold; a flag given always wins (issue 52: also at the command's own default), and where it differs
    from the run's it is said in one line."""
    from jaxpose import reconstruct
    from jaxpose import export
    from jaxpose.serving.inference import parse_with_run
    from jaxpose.rig.config import recorded_settings
    from jaxpose.training.run_directory import RunDirectory, RunRecord, prepare_run_dir, read_record, write_record

    trained = RigProjectConfig(
        root=tmp_path / "project", calibration=tmp_path / "rig.toml", calibration_unit="m", sync="auto", frame_offsets=("cam02=3",),
        min_confidence=0.2, image_size=(1920, 1080), validation_fraction=0.3, train_stride=2,
    )
    run_dir = tmp_path / "run"
    prepare_run_dir(_experiment(run_dir, overwrite=False))
    write_record(RunDirectory(run_dir), RunRecord(project=recorded_settings(trained, "coco17")))
    record = read_record(RunDirectory.of(run_dir / "checkpoints"))  # the checkpoints folder names the same run
    expected = dataclasses.replace(trained, skeleton="coco17", validation_fraction=0.2, train_stride=1)  # the split is not carried
    assert record.project == expected.resolved()
    argv = ["--checkpoint", str(run_dir), "--output", str(tmp_path / "motion"), "--fps", "50"]
    assert reconstruct.parse(argv).data == expected.resolved()
    assert "trained with" not in capsys.readouterr().err
    overridden = reconstruct.parse([*argv, "--data.sync", "given", "--data.min-confidence", "0.3"]).data
    assert overridden.min_confidence == 0.3 and overridden.sync == "given"  # given at the default: still given
    assert capsys.readouterr().err.splitlines() == [
        "--data.min-confidence 0.3 given; the run was trained with 0.2", "--data.sync given given; the run was trained with auto"
    ]
    def export_threshold(run, *flags):
        args, _, _ = parse_with_run(export.ExportArgs, [str(run), *flags], export.__doc__, "python -m jaxpose.export", run_field="run_dir")
        return args.min_confidence

    assert export_threshold(run_dir / "checkpoints") == 0.2
    assert export_threshold(tmp_path / "old_run") == 0.05  # a run from before the record
    assert export_threshold(run_dir, "--min-confidence", "0.05") == 0.05
    assert "--min-confidence 0.05 given; the run was trained with 0.2" in capsys.readouterr().err


@pytest.mark.trains  # the shared rig run (tests/conftest.py)
def test_a_recording_no_camera_detects_is_said_and_skipped(rig_run, tmp_path, capsys):
    """Issue 42 case 8: a recording whose every score is below --data.min-confidence ended the command in
    "map_in_chunks: expected arrays of one non-zero length" after the other recordings' files were written;
    it is one line naming the recording, listed as skipped, and the others are written."""
    from jaxpose import reconstruct

    project = _copy_project(rig_run.project, tmp_path / "project")
    _set_scores(project.glob("reaching02/*_json/*.json"), 0.05)  # below the run's --data.min-confidence, 0.1
    before = _snapshot(project)
    report = reconstruct.main(["--checkpoint", str(rig_run.run_dir), "--data.root", str(project), "--output", str(tmp_path / "motion"), "--fps", "50", "--no-progress"])
    said = [line for line in capsys.readouterr().err.splitlines() if "no camera detects" in line]
    assert said == ["recording reaching02: no camera detects the person at any instant (scores below --data.min-confidence 0.1, or no detection): no file written"]
    rows = {row["recording"]: row for row in report["recordings"]}
    assert rows["reaching02"]["skipped"] == "no detection" and rows["reaching02"]["files"] == []
    assert (tmp_path / "motion" / "walking01.trc").is_file() and not list((tmp_path / "motion").glob("reaching02*"))
    assert "| reaching02 |" in (tmp_path / "motion" / "report.md").read_text()
    assert _snapshot(project) == before


@pytest.mark.trains
def test_a_diverging_run_stops_with_a_message_and_no_nonfinite_checkpoint(tmp_path):
    """Issue 42 case 5: --optimizer.learning-rate nan is refused before anything is read or written (it trained
    and exited 0 with a NaN report), and a finite rate that diverges (1e30) stops the job with one line and a
    non-zero exit, leaving no checkpoint with a non-finite weight for a resume to load."""
    from experiments import synthetic

    def job(rate: str, run_dir):
        argv = [
            "--preset", "tiny", "--train.epochs", "1", "--train.batch-size", "64", "--train.checkpoint-every", "2",
            "--train.log-every", "3", "--data.generator.samples-per-subject", "150", "--optimizer.learning-rate", rate,
            "--run.run-dir", str(run_dir), "--run.no-progress",
        ]  # fmt: skip
        with pytest.raises(SystemExit) as stop:
            synthetic.main(argv)
        message = str(stop.value.code)
        assert "\n" not in message
        return message

    assert job("nan", tmp_path / "nan") == "error: --optimizer.learning-rate must be a positive finite number, got nan"
    assert not (tmp_path / "nan").exists()
    message = job("1e30", tmp_path / "diverged")
    assert re.search(r"training diverged at step \d+: (the loss is (nan|inf)|the weights are not finite)", message), message
    kept = re.search(r"the last checkpoint, step (\d+), is finite and kept", message)
    if kept:  # what a resume would load: every weight finite
        import jax

        from jaxpose.serving import inference

        lifter = inference.load(tmp_path / "diverged")
        assert all(np.isfinite(leaf).all() for leaf in jax.tree.leaves(jax.device_get(lifter.variables)))
    else:
        assert "no checkpoint was written" in message


def test_a_broken_lifter_scores_worse_than_the_truth_on_every_measure(small_project):
    """Issue 42 case 5: joints that came out NaN or behind the camera were left out of the reprojection, so a
    diverged lifter scored 2.7 px where a trained one scored 84 px; what a measure cannot score now counts as
    a failure, far worse than the true poses (the best a lifter can do) on all three measures."""
    from jaxpose.training import evaluation, pseudo_labelling, self_consistency
    from jaxpose.training.config import PseudoLabelConfig

    before = _snapshot(small_project)
    test = pseudo_labelling.label(load_rig_project(RigProjectConfig(root=small_project), progress=False).validation, PseudoLabelConfig())
    truth, _ = evaluation.ground_truth_in_views(test)

    def measures(lifted):
        return self_consistency.self_consistency(lifted, test, test.samples.pseudo3d, test.samples.pseudo3d_weight > 0)

    exact, diverged = measures(truth), measures(np.full_like(truth, np.nan))
    for name in self_consistency.METRICS:
        assert diverged[name]["overall"] == self_consistency.FAILED > 10 * exact[name]["overall"], name
    behind = truth.copy()
    behind[:, 0] += np.asarray([0.0, 0.0, -1e5])  # view 0's lifts placed 100 m behind the other cameras
    assert measures(behind)["reprojection_px"]["per_camera"][0] > 100 > exact["reprojection_px"]["per_camera"][0]
    assert _snapshot(small_project) == before


def test_a_point_the_lens_cannot_undistort_is_nan_and_the_others_match_opencv():
    """The lens inversion converges (OpenCV's undistortPoints, iterated to convergence, as the oracle) inside
    the image and says NaN far outside it, where the fixed-point iteration does not converge."""
    import cv2
    import jax.numpy as jnp

    from jaxpose.camera import undistort_points

    K = np.array([[1000.0, 0, 960], [0, 1000.0, 540], [0, 0, 1]])
    dist = np.array([-0.3, 0.08, 0.0, 0.0, 0.0])
    inside = np.array([[10.0, 20.0], [960.0, 540.0], [1900.0, 1060.0], [100.0, 900.0]])
    cameras = Cameras(K=jnp.asarray(K[None]), R=jnp.eye(3)[None], t=jnp.zeros((1, 3)), dist=jnp.asarray(dist[None]))
    ours = np.asarray(undistort_points(cameras, jnp.asarray(np.concatenate([inside, [[5000.0, 540.0], [1e6, 1e6]]])[None])))[0]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    oracle = cv2.undistortPoints(inside[:, None], K, dist, None, K, criteria=criteria)[:, 0]
    np.testing.assert_allclose(ours[:4], oracle, atol=0.05)
    assert np.isnan(ours[4:]).all()


@pytest.mark.parametrize("far", [5000.0, 1e6])
def test_one_far_off_keypoint_is_undetected_and_the_project_loads(small_project, tmp_path, far):
    """Issue 42 case 6: one keypoint at 5,000 px (or 1e6) in one frame of one camera made the rig path's
    undistortion diverge ("cannot convert float NaN to integer"); it is now undetected, as predict's
    --outside-margin makes it, and everything prepared is finite."""
    project = _copy_project(small_project, tmp_path / "project")
    frame = sorted(project.glob("*/cam02_json/*.json"))[5]
    content = json.loads(frame.read_text())
    content["people"][0]["pose_keypoints_2d"][27:29] = [far, far / 2]  # joint 9 (left wrist, COCO-17)
    frame.write_text(json.dumps(content))
    before = _snapshot(project)
    data = load_rig_project(RigProjectConfig(root=project), progress=False)
    for part in (data.train, data.validation):
        assert np.isfinite(np.asarray(part.samples.keypoints2d)).all() and np.isfinite(np.asarray(part.samples.confidence)).all()
    assert (np.asarray(data.train.samples.keypoints2d) < 3000).all()
    assert _snapshot(project) == before


@pytest.mark.skipif(not paths.FORMATS.is_dir(), reason="needs ../shared/data/formats (real sample files)")
def test_body25_and_body25b_are_told_apart_by_their_joint_8():
    """Issue 42 case 7: Pose2Sim's default BODY_25B frames read as BODY_25 (as a BODY_25 lifter read them,
    152 mm per joint off) are refused naming the layout, and real BODY_25 output read as BODY_25B too; each
    read as what it is passes."""
    from jaxpose.formats.keypoint_files import read_openpose_folder
    from jaxpose.layouts import check_body25_layout

    body25b = read_openpose_folder(paths.FORMATS / "openpose-json" / "pose2sim_demo_balancing_body25b" / "cam03_json")
    keypoints, scores = body25b.keypoints.reshape(-1, 25, 2), body25b.scores.reshape(-1, 25)
    check_body25_layout("body25b", keypoints, scores, "cam03_json", "--format")
    with pytest.raises(ValueError, match=r"cam03_json: read as body25, but joint 8 is not the midpoint .* this is BODY25B output; pass --format body25b"):
        check_body25_layout("body25", keypoints, scores, "cam03_json", "--format")
    spin = json.loads((paths.FORMATS / "openpose-json" / "spin_im1010_single_image" / "im1010_openpose.json").read_text())
    values = np.repeat(np.asarray(spin["people"][0]["pose_keypoints_2d"], np.float32).reshape(1, 25, 3), 3, axis=0)  # its one pose, thrice
    check_body25_layout("body25", values[..., :2], values[..., 2], "im1010", "--format")
    with pytest.raises(ValueError, match=r"read as body25b, but joint 8 is the midpoint .* this is BODY25 output"):
        check_body25_layout("body25b", values[..., :2], values[..., 2], "im1010", "--format")


@pytest.mark.parametrize("number", ["000100000000", "200000", "9223372036854775808"])
def test_a_stray_frame_number_is_refused_naming_its_file(small_project, tmp_path, number):
    """Issue 42 cases 8 and 9: one stray frame file numbered 000100000000 made the loader allocate 53.6 GiB
    (200000: a 70 MB file of empty rows), and 2^63 ended in an OverflowError traceback; each is one line
    naming the file, and the project is left as it was."""
    project = _copy_project(small_project, tmp_path / "project")
    folder = next(project.glob("*/cam02_json"))
    first = sorted(folder.glob("*.json"))[0]
    stray = folder / first.name.replace("000000000000", number.rjust(12, "0"))
    shutil.copy(first, stray)
    before = _snapshot(project)
    with pytest.raises(ValueError, match=rf"{stray.name}|frame number {int(number)}") as refusal:
        load_rig_project(RigProjectConfig(root=project), progress=False)
    assert "\n" not in str(refusal.value)
    assert _snapshot(project) == before


def test_coco_and_npz_frame_numbers_are_checked_too(tmp_path):
    from jaxpose.formats import detections_npz
    from jaxpose.formats.keypoint_files import read_coco_results

    entries = [{"image_id": image, "category_id": 1, "keypoints": [1.0, 2.0, 0.9] * 17, "score": 0.9} for image in ("f1.jpg", "f2.jpg", f"f{2**63}.jpg")]
    (tmp_path / "coco.json").write_text(json.dumps(entries))
    with pytest.raises(ValueError, match=r"coco.json: .*9223372036854775808"):
        read_coco_results(tmp_path / "coco.json")
    np.savez(tmp_path / "detections.npz", keypoints=np.zeros((3, 2, 17, 2), np.float32), confidence=np.ones((3, 2, 17), np.float32),
             frames=np.array([0, 1, 10**9]), camera_names=np.array(["a", "b"]), skeleton="coco17")  # fmt: skip
    with pytest.raises(ValueError, match=r"field 'frames'.*row 2 \(frame 1,000,000,000\) lies"):
        detections_npz.read(tmp_path / "detections.npz")


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--train.batch-size", "0"], "--train.batch-size must be >= 1, got 0"),
        (["--train.batch-size", "-1"], "--train.batch-size must be >= 1, got -1"),
        (["--model.width", "0"], "--model.width must be >= 1, got 0"),
        (["--optimizer.learning-rate", "inf"], "--optimizer.learning-rate must be a positive finite number, got inf"),
    ],
)
def test_numbers_no_run_can_take_are_one_line_before_anything_is_written(tmp_path, flags, message):
    """Issue 42 case 9: --train.batch-size 0 or -1 and --model.width 0 ended in tracebacks (-1 after writing
    config.json)."""
    from experiments import synthetic

    with pytest.raises(SystemExit) as stop:
        synthetic.main(["--preset", "tiny", "--run.run-dir", str(tmp_path / "run"), *flags])
    assert str(stop.value.code) == f"error: {message}"
    assert not (tmp_path / "run").exists()


# The property: whatever inputs, outputs and flags point into each other, a command changes nothing but its
# named outputs (and its own cache).  The run is a trained one (the synthetic tiny preset), so predict and
# export do their whole work where their outputs are allowed; reconstruct, given a lifter of other joints,
# stops once the project is read.
def _command_argv(command: str, paths: dict, output, extra, overwrite: bool) -> tuple[list[str], list, list]:
    """(argv, the outputs it names, its inputs) of `command` with `output` (and `extra`, a second output) from the pool."""
    flag = ["--overwrite"] if overwrite else []
    if command == "predict":
        argv = ["--checkpoint", paths["run"], "--input", paths["frames"], "--output", output, "--plot", extra, "--plot-count", "1",
                "--image-size", "1920", "1080", *flag]  # fmt: skip
        return argv, [output, extra], [paths["frames"], paths["run"]]
    if command == "export":
        return [paths["run"], "--output", output, "--no-onnx", *flag], [output], [paths["run"]]
    if command == "calibrate":
        return ["--input", paths["npz"], "--output", output, *flag], [output], [paths["npz"]]
    return ["--checkpoint", paths["run"], "--data.root", paths["project"], "--output", extra, "--fps", "50", "--no-progress", *flag], [extra], [paths["project"], paths["run"]]


def _allowed(path, named) -> bool:
    """A named output, a file beside a named file output with its stem (a report, a figure), inside a named
    folder output, or a cache."""
    for output in map(lambda p: p.resolve(), named):
        if path == output or path.is_relative_to(output) or (path.parent == output.parent and path.stem.split(".")[0] == output.stem):
            return True
    return ".jaxpose_cache" in path.parts


@pytest.fixture(scope="module")
def workspace(tmp_path_factory, small_project, trained_run):
    root = tmp_path_factory.mktemp("property")
    _copy_project(small_project, root / "project")
    shutil.copytree(trained_run[0], root / "run")
    (root / "out").mkdir()
    (root / "out" / "poses.json").write_text("earlier")
    np.savez(root / "detections.npz", keypoints=np.zeros((2, 2, 17, 2), np.float32), confidence=np.ones((2, 2, 17), np.float32))
    return root


@pytest.mark.trains  # the shared tiny run (tests/conftest.py)
def test_no_command_touches_a_path_outside_its_named_outputs(workspace, tmp_path):
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from jaxpose import calibrate, export, predict, reconstruct

    mains = {"predict": predict.main, "export": export.main, "calibrate": calibrate.main, "reconstruct": reconstruct.main}
    frames = next((workspace / "project").glob("*/cam01_json"))
    pool = [
        workspace / "new.json", workspace / "out" / "poses.json", workspace / "out", workspace / "out" / "plots", workspace / "project",
        workspace / "project" / "poses.json", frames, frames / "poses.json", next(frames.glob("*.json")), workspace / "run",
        workspace / "run" / "config.json", workspace / "run" / "lifter.onnx", workspace / "detections.npz", workspace / "cameras.json",
        workspace / "motion", workspace / "project" / "motion", workspace,
    ]  # fmt: skip
    paths = {"run": workspace / "run", "frames": frames, "npz": workspace / "detections.npz", "project": workspace / "project"}

    @settings(max_examples=int(os.environ.get("HARDEN_EXAMPLES", 40)), deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.sampled_from(sorted(mains)), st.sampled_from(pool), st.sampled_from(pool), st.booleans())
    def check(command, output, extra, overwrite):
        argv, named, inputs = _command_argv(command, paths, output, extra, overwrite)
        before = _snapshot(workspace)
        with contextlib.suppress(SystemExit):
            mains[command]([str(a) for a in argv])
        after = _snapshot(workspace)
        touched = {name for name in before.keys() | after.keys() if before.get(name) != after.get(name)}
        outside = sorted(name for name in touched if not _allowed((workspace / name).resolve(), named))
        assert outside == [], f"{command} {argv}: touched {outside}"
        into_inputs = sorted(
            name for name in touched
            if ".jaxpose_cache" not in pathlib.Path(name).parts and any((workspace / name).resolve().is_relative_to(i.resolve()) for i in inputs)
        )  # fmt: skip
        assert into_inputs == [], f"{command} {argv}: wrote into its inputs {into_inputs}"
        for name in touched:  # each example starts from the same workspace: what was written is removed
            if name in before and before[name] is not None:
                (workspace / name).write_bytes(before[name])
            else:
                (workspace / name).unlink(missing_ok=True)

    check()


def test_smaller_cases_of_issue_42(tmp_path, small_project):
    """--fps inf was accepted (every Time 0); a recording named with a tab or a line break broke the TRC header."""
    from jaxpose import predict, reconstruct
    from jaxpose.formats.trc import read_trc, write_trc

    for main, argv in (
        (predict.main, ["--checkpoint", str(tmp_path / "run"), "--input", str(tmp_path / "in.json"), "--output", str(tmp_path / "o.json")]),
        (reconstruct.main, ["--checkpoint", str(tmp_path / "run"), "--data.root", str(small_project), "--output", str(tmp_path / "m")]),
    ):
        _refused(main, [*argv, "--fps", "inf"], r"--fps must be a positive finite number, got inf")
    path = write_trc(tmp_path / "walk\t01\nb.trc", np.zeros((3, 2, 3)), ["A", "B"], 50.0)
    header = path.read_text().split("\n")[0]
    assert header.split("\t")[3] == "walk 01 b.trc"
    assert read_trc(path).markers.shape == (3, 2, 3)


def test_a_full_disk_a_read_only_folder_and_a_device_are_one_line_each(tmp_path, monkeypatch):
    """Issue 42 case 9, simulated by the OS errors they raise (the suite may run as root): a full disk keeps
    the earlier file and says so; an output folder that cannot be made; a calibration linked to /dev/zero."""
    import errno

    from jaxpose.formats import outputs
    from jaxpose.formats.calibration_files import read_rig_calibration
    from jaxpose.formats.errors import DataFormatError

    target = tmp_path / "poses.json"
    target.write_text("earlier")

    def full(*_):
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(outputs.OutputError, match=r"poses.json: could not be written \(No space left on device\); the earlier file is kept"):
        with outputs.atomic_output(target) as temporary:
            temporary.write_text("new")
            monkeypatch.setattr(outputs.os, "replace", full)
    monkeypatch.undo()
    assert target.read_text() == "earlier" and sorted(p.name for p in tmp_path.iterdir()) == ["poses.json"]

    def read_only(*_, **__):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(outputs.Path, "mkdir", read_only)
    with pytest.raises(outputs.OutputError, match=r"--output .*out/poses.json: its folder .* cannot be made \(Read-only file system\)"):
        outputs.check_output(tmp_path / "out" / "poses.json", overwrite=False)
    monkeypatch.undo()
    (tmp_path / "calibration.toml").symlink_to("/dev/zero")
    with pytest.raises(DataFormatError, match="not a regular file"):
        read_rig_calibration(tmp_path / "calibration.toml")


_WITHOUT_A_SIZE_LIMIT = """
import jax, jax.numpy as jnp
for n in (1, 2, 3):
    jax.jit(lambda x: jnp.sin(x) * n)(jnp.ones(n)).block_until_ready()
"""
_JAXPOSE = """
import jax, jax.numpy as jnp
from jaxpose.compilation_cache import enable_compilation_cache
enable_compilation_cache()
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)  # these programs compile in milliseconds
for n in (4, 5, 6):
    jax.jit(lambda x: jnp.cos(x) * n)(jnp.ones(n)).block_until_ready()
"""


@pytest.mark.processes
def test_a_compilation_cache_written_without_a_size_limit_fails_no_later_write(tmp_path):
    """Issue 42 case 10, the reproduction: a process without a size limit on the shared cache
    (JAX_COMPILATION_CACHE_DIR naming it, an earlier jaxpose, JAX without filelock) writes programs without
    the access-time file that JAX's eviction reads for every program; every jaxpose process (which has the
    limit) then printed "Error writing persistent compilation cache entry" at every compilation and cached
    nothing.  Now jaxpose writes its programs, each program has its access time, and those there before are
    unchanged."""
    from python_process import run_python

    from jaxpose.compilation_cache import ACCESS_TIME, PROGRAM, WRITE_ERROR

    folder = tmp_path / "xla"
    other = run_python(_WITHOUT_A_SIZE_LIMIT, tmp_path, JAX_COMPILATION_CACHE_DIR=str(folder), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    assert other.returncode == 0, other.stderr
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    assert any(name.endswith(PROGRAM) for name in before) and not any(name.endswith(ACCESS_TIME) for name in before)
    ours = run_python(_JAXPOSE, tmp_path, JAXPOSE_COMPILATION_CACHE=str(folder))
    assert ours.returncode == 0 and WRITE_ERROR not in ours.stderr and "could not take a program" not in ours.stderr, ours.stderr
    programs = {path.name.removesuffix(PROGRAM) for path in folder.glob(f"*{PROGRAM}")}
    assert len(programs) > sum(name.endswith(PROGRAM) for name in before)  # jaxpose's own were written
    assert {path.name.removesuffix(ACCESS_TIME) for path in folder.glob(f"*{ACCESS_TIME}")} == programs
    assert all((folder / name).read_bytes() == content for name, content in before.items())


def test_a_compilation_cache_that_cannot_take_a_program_is_one_line_not_one_per_compilation(caplog, monkeypatch):
    """Issue 42 case 10: where the cache still cannot take a program (a full disk), JAX warns at every
    compilation; the first such warning becomes one line naming the folder and the reason, the rest are not
    shown, other warnings are untouched."""
    import warnings

    from jaxpose.compilation_cache import WRITE_ERROR, quiet_write_errors

    shown = []
    monkeypatch.setattr(warnings, "showwarning", lambda message, *rest, **keywords: shown.append(str(message)))
    quiet_write_errors("/tmp/xla")
    quiet_write_errors("/tmp/xla")  # a second call wraps nothing twice
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        for module in ("jit_step", "jit_eval", "jit_label"):
            warnings.warn(f"{WRITE_ERROR} for '{module}': OSError: [Errno 28] No space left on device", UserWarning)
        warnings.warn("another warning", UserWarning)
    assert shown == ["another warning"]
    lines = [record.getMessage() for record in caplog.records if "compilation cache" in record.getMessage()]
    assert len(lines) == 1 and "/tmp/xla could not take a program (OSError: [Errno 28] No space left on device)" in lines[0]


@pytest.mark.parametrize("held", ["every recording held out", "every score below the threshold"])
def test_no_training_sample_left_says_why(small_project, tmp_path, held):
    """Issue 42 case 10: with every recording held out, or every score below --data.min-confidence, the run
    stopped on "--train.batch-size 256 is larger than the training set (0 samples); choose at most 0"."""
    from experiments import rig

    project = _copy_project(small_project, tmp_path / "project")
    flags = ["--data.validation-recordings", "reaching02", "walking01"] if held == "every recording held out" else ["--data.min-confidence", "0.999"]
    before = _snapshot(project)
    _refused(
        rig.main, ["--data.root", str(project), "--run.run-dir", str(tmp_path / "run"), "--run.no-progress", *flags],
        r"^error: no training sample is left: every instant was held out \(--data.validation-\*\)$" if held == "every recording held out" else
        r"^error: no training sample is left: all \d+ training instants have fewer usable views than --pseudo-labels.min-views 2"
        r" \(scores below the data's score threshold, e.g. --data.min-confidence\)$",
    )
    assert _snapshot(project) == before and not (tmp_path / "run").exists()


def test_leaving_out_training_samples_names_their_recordings(small_project, tmp_path, capsys):
    """Issue 42 case 10: "leaving out N training samples with fewer than 2 usable views" did not say from which
    recordings; only walking01 has such instants (its first 4 frames, seen by cam01 alone).  A batch larger
    than what is left then stops the run in one line, before anything is written."""
    from experiments import rig

    project = _copy_project(small_project, tmp_path / "project")
    _set_scores([frame for camera in ("cam02", "cam03", "cam04") for frame in sorted(project.glob(f"walking01/{camera}_json/*.json"))[:4]], 0.0)
    before = _snapshot(project)
    _refused(
        rig.main, ["--data.root", str(project), "--run.run-dir", str(tmp_path / "run"), "--run.no-progress", "--train.batch-size", "64"],
        r"^error: --train.batch-size 64 is larger than the training set \(28 samples\); choose at most 28$",
    )
    said = [line.split(" WARNING ", 1)[1] for line in capsys.readouterr().err.splitlines() if "leaving out" in line]
    assert said == ["leaving out 4 training samples with fewer than 2 usable views (walking01: 4)"]
    assert _snapshot(project) == before and not (tmp_path / "run").exists()


@pytest.mark.trains  # the shared rig run (tests/conftest.py)
def test_the_training_line_says_where_max_steps_stops_it(rig_run):
    """Issue 42 case 10: "training: ... (770 steps)" was logged whatever --train.max-steps; the line says where
    the cap (10) stops the run, and the run stops there."""
    (line,) = [line for line in rig_run.log.splitlines() if " INFO training: " in line]
    assert re.search(r", 4 epochs \((\d+) steps; stopping at step 10 \(--train.max-steps\)\), from step 0$", line), line
    assert int(re.search(r"\((\d+) steps;", line)[1]) > 10
    assert max(int(path.name) for path in (rig_run.run_dir / "checkpoints").iterdir()) == 10


def test_a_camera_at_half_the_frame_rate_is_named_by_sync(small_project, tmp_path):
    """Issue 42 case 10: with --data.sync auto, a camera at half the others' frame rate (its frames numbered 0,
    1, 2, ... as a 25 fps camera's are) was blamed on the person ("too little motion"); the warning names the
    camera and the frame rate, in one line, for the log and the report."""
    from experiments import rig

    project = _copy_project(small_project, tmp_path / "project")
    for folder in project.glob("*/cam02_json"):
        for index, frame in enumerate(sorted(folder.glob("*.json"))):
            if index % 2:
                frame.unlink()
            else:
                frame.rename(frame.with_name(frame.name.replace(f"{index:012d}", f"{index // 2:012d}")))
    before = _snapshot(project)
    config = RigProjectConfig(root=project, sync="auto")
    loaded = load_rig_project(config, progress=False)
    expected = ("frame offsets UNRELIABLE: camera cam02 has 10 frames against the others' 20: another frame rate? Every camera must run"
                " at one rate (resample it, or leave it out)")  # fmt: skip
    assert [r.warnings for r in loaded.recordings] == [(expected,)] * 2
    assert f"- walking01: {expected}" in rig.project_notes(loaded, config)[0]
    assert _snapshot(project) == before


def test_what_loading_finds_suspect_is_in_the_report(small_project, tmp_path):
    """Issue 42 case 10: a calibration whose people come out three times an adult's size (limbs of metres: a
    warning, not a wrong unit's refusal) and a frame offset of 100,000 that leaves a camera sharing no instant
    with the others trained without a word in the report; each is one line naming the file or the camera, in
    the log and under the report's recordings table."""
    from experiments import rig
    from jaxpose.rig.timeline import lone_cameras

    views = {"a": (np.arange(10), None, None), "b": (np.arange(5, 15), None, None), "c": (np.arange(10), None, None)}
    assert lone_cameras(views, {}) == [] and lone_cameras(views, {"c": 100_000}) == ["c"]
    project = _copy_project(small_project, tmp_path / "project")
    calibration = project / "calibration.toml"
    text = calibration.read_text()
    calibration.write_text(re.sub(r"translation = \[([^\]]*)\]", lambda m: "translation = [" + ", ".join(str(3 * float(v)) for v in m[1].split(",")) + "]", text))
    before = _snapshot(project)
    config = RigProjectConfig(root=project, frame_offsets=("cam03=100000",))
    loaded = load_rig_project(config, progress=False)
    (sanity,) = loaded.warnings
    assert re.fullmatch(rf"{calibration}: the people in view have limbs of .* mm where an adult's are .* mm: is the calibration right\?", sanity)
    lone = "camera cam03 (frame offset +100000) shares no instant with the other cameras: are --data.frame-offsets right?"
    assert [r.warnings for r in loaded.recordings] == [(lone,)] * 2
    notes = rig.project_notes(loaded, config)[0]
    assert "**Warnings of loading**" in notes and f"- {sanity}" in notes and f"- walking01: {lone}" in notes
    assert load_rig_project(config, progress=False).warnings == loaded.warnings  # kept with the prepared project
    assert _snapshot(project) == before


def _c3d_integer_parameters(path: pathlib.Path) -> dict[str, list[int]]:
    """Every 16-bit integer parameter of an Intel C3D file, as GROUP:NAME -> its values read unsigned, parsed
    from the bytes (the C3D user guide's layout): the oracle for what ezc3d wrote."""
    data = path.read_bytes()
    start = (data[0] - 1) * 512 + 4  # header word 1, first byte: the parameter section's first block
    groups, parameters, at = {}, {}, start
    while True:
        length, index = (int(v) for v in np.frombuffer(data[at : at + 2], np.int8))
        if length == 0:
            return {f"{groups[group]}:{name}": values for (group, name), values in parameters.items()}
        name = data[at + 2 : at + 2 + abs(length)].decode()
        following = at + 2 + abs(length)
        step = int(np.frombuffer(data[following : following + 2], np.int16)[0])
        if index < 0:
            groups[-index] = name
        elif data[following + 2] == 2:  # type int16
            dims = data[following + 4 : following + 4 + data[following + 3]]
            count = int(np.prod(list(dims)))
            values = np.frombuffer(data[following + 4 + len(dims) :][: 2 * count], np.uint16)
            parameters[(index, name)] = [int(v) for v in values]
        if step == 0:
            return {f"{groups[group]}:{name}": values for (group, name), values in parameters.items()}
        at = following + step


@pytest.mark.parametrize("first_frame", [5, 65530, 70000])
def test_a_c3d_first_frame_past_16_bits_is_not_wrapped(tmp_path, first_frame):
    """Issue 52 defect 5: frames 70000-70149 were written with the header's first frame 4464 (70000 + 1 wrapped
    at 65536) beside the .trc's OrigDataStartFrame 70000.  The range is in TRIAL:ACTUAL_START_FIELD /
    ACTUAL_END_FIELD (two 16-bit words, low first; C3D counts from 1), and the header holds the true first frame
    when the last fits 16 bits, else the range 1..N as the C3D user guide advises: never a wrapped number."""
    ezc3d = pytest.importorskip("ezc3d")
    from jaxpose.formats.c3d import write_c3d

    frames = 150
    path = write_c3d(tmp_path / "walk.c3d", np.zeros((frames, 2, 3)), ["A", "B"], 50.0, "mm", first_frame)
    words = [int(w) for w in np.frombuffer(path.read_bytes()[:12], np.uint16)]  # header words 1-6: 4 and 5 the range
    fits = first_frame + frames <= 0xFFFF
    assert (words[3], words[4]) == ((first_frame + 1, first_frame + frames) if fits else (1, frames))
    parameters = _c3d_integer_parameters(path)
    start, end = parameters["TRIAL:ACTUAL_START_FIELD"], parameters["TRIAL:ACTUAL_END_FIELD"]
    assert start[0] + 65536 * start[1] == first_frame + 1 and end[0] + 65536 * end[1] == first_frame + frames
    read = ezc3d.c3d(str(path))  # the reader agrees with the bytes
    assert read["header"]["points"]["first_frame"] == words[3] - 1
    assert [v & 0xFFFF for v in read["parameters"]["TRIAL"]["ACTUAL_START_FIELD"]["value"]] == start


def _reconstruct_argv(rig_run, project, output, *extra) -> list[str]:
    return ["--checkpoint", str(rig_run.run_dir), "--data.root", str(project), "--output", str(output), "--fps", "50", "--no-progress", *extra]


def _files_and_report(output: pathlib.Path) -> tuple[set[str], set[str]]:
    """The recordings' files in `output` and those its report.json lists."""
    report = json.loads((output / "report.json").read_text())
    present = {path.name for path in output.iterdir() if path.name not in ("report.md", "report.json")}
    return present, {name for row in report["recordings"] for name in row["files"]}


@pytest.mark.trains  # the shared rig run (tests/conftest.py)
@pytest.mark.processes
def test_two_reconstructs_into_one_output_keep_its_report_whole(rig_run, tmp_path, monkeypatch):
    """Issue 52 defect 8: two reconstructs of different recordings into one --output at once both exited 0 and
    report.md listed one recording.  Here a second process starts while this one writes its first file: it
    stops in one line naming the holder, and the folder's report lists every file in the folder."""
    from jaxpose import reconstruct
    from python_process import run_python

    output, second = tmp_path / "motion", []
    write_motion = reconstruct.motion_files.write_motion

    def write_while_another_starts(*args, **kwargs):
        if not second:
            argv = _reconstruct_argv(rig_run, rig_run.project, output, "--data.recordings", "walking01")
            second.append(run_python(f"from jaxpose import reconstruct; reconstruct.main({argv!r})", tmp_path))
        return write_motion(*args, **kwargs)

    monkeypatch.setattr(reconstruct.motion_files, "write_motion", write_while_another_starts)
    reconstruct.main(_reconstruct_argv(rig_run, rig_run.project, output, "--data.recordings", "reaching02"))
    (other,) = second
    last = other.stderr.strip().splitlines()[-1]
    assert other.returncode != 0 and "Traceback" not in other.stderr, other.stderr
    assert re.fullmatch(rf"--output {output} is in use by another jaxpose.reconstruct \(process {os.getpid()} on .*\); wait for it to end, or choose another --output", last), last
    present, listed = _files_and_report(output)
    assert present == listed and {"reaching02.csv", "reaching02.npz", "reaching02.trc"} <= listed
    assert not any(name.startswith("walking01") for name in present)


@pytest.mark.trains
def test_ctrl_c_during_reconstruct_is_one_line_and_a_report_of_what_was_written(rig_run, tmp_path, monkeypatch, capsys):
    """Issue 52 defect 11: Ctrl-C printed a traceback and left files without a report.  Pressed while the first
    recording's files are written, they are finished, the report lists them and the recording not done, the
    command says so in one line and exits 130 (the shell's code for Ctrl-C)."""
    import signal

    from jaxpose import reconstruct

    write_motion = reconstruct.motion_files.write_motion

    def pressed_while_writing(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        return write_motion(*args, **kwargs)

    monkeypatch.setattr(reconstruct.motion_files, "write_motion", pressed_while_writing)
    output = tmp_path / "motion"
    # Ctrl-C as a shell's command meets it (Python's default handler): one run of the suite met another here,
    # left by an earlier test in the same worker; which one is said if it happens again.
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        reconstruct.main(_reconstruct_argv(rig_run, rig_run.project, output))
        pytest.fail(f"Ctrl-C was not seen (SIGINT's handler before the test: {before!r})")
    except KeyboardInterrupt:
        pytest.fail("Ctrl-C came out of the command as a traceback")
    except SystemExit as stop:
        assert stop.code == 130
    finally:
        signal.signal(signal.SIGINT, before)
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "Ctrl-C" in line]
    assert line == f"jaxpose.reconstruct: interrupted (Ctrl-C): 1 of 2 recordings written (each whole), listed in {output / 'report.md'}"
    present, listed = _files_and_report(output)  # reaching02 first: its gap splits it in two segments
    assert present == listed == {"reaching02.csv", "reaching02.npz", "reaching02.trc", "reaching02.seg1.trc"}
    report = json.loads((output / "report.json").read_text())
    assert report["interrupted"] == {"after": 1, "of": 2, "not_reconstructed": ["walking01"]}
    assert "**Interrupted (Ctrl-C)** after 1 of 2 recordings; not reconstructed: walking01." in (output / "report.md").read_text()


@pytest.mark.trains
def test_a_recording_too_short_for_limb_lengths_is_reported_as_smoothed_without_them(rig_run, tmp_path):
    """Issue 52 defect 11: a recording of under 10 frames got no limb constraint (no limb measured at
    `MIN_LENGTH_INSTANTS` instants) while the report said "solved over time" as for the others; the report says
    how many limbs the trajectory held, per recording: none for 8 frames, every one for 160."""
    from jaxpose import reconstruct
    from jaxpose.reconstruction.trajectory import MIN_LENGTH_INSTANTS

    project = _copy_project(rig_run.project, tmp_path / "project")
    for frame in project.glob("walking01/*_json/*.json"):
        if int(re.search(r"_(\d{12})_keypoints", frame.name)[1]) >= 8:
            frame.unlink()
    report = reconstruct.main(_reconstruct_argv(rig_run, project, tmp_path / "motion"))
    rows = {row["recording"]: row for row in report["recordings"]}
    limbs = len(rows["reaching02"]["limb_length_std_mm"])
    assert 8 < MIN_LENGTH_INSTANTS and rows["walking01"]["frames"] == 8
    assert rows["walking01"]["limbs_held"] == 0 and len(rows["walking01"]["limbs_free"]) == limbs
    assert rows["reaching02"]["limbs_held"] == limbs and rows["reaching02"]["limbs_free"] == []
    markdown = (tmp_path / "motion" / "report.md").read_text()
    assert f"| walking01 | 0 of {limbs} (no limb measured at {MIN_LENGTH_INSTANTS} instants: smoothed without limb lengths) |" in markdown
    assert f"| reaching02 | {limbs} of {limbs} |" in markdown


@pytest.fixture(scope="module")
def uncalibrated_project(tmp_path_factory):
    """The example project of 2 recordings of 60 frames, walking01 and waving02, without its calibration.toml:
    the rig is recovered (walking01 first: the person walks through the scene)."""
    config = ExampleProjectConfig(recordings=2, frames_per_recording=60, motions=("walking", "waving"))
    project = write_rig_project(tmp_path_factory.mktemp("uncalibrated") / "project", config)
    (project / "calibration.toml").unlink()
    return project


def test_a_session_naming_a_recording_the_project_lacks_is_refused_with_the_closest_name(uncalibrated_project, tmp_path):
    """Issue 52 defect 11: `--data.sessions b=walkng03` (a typo) was taken for a recording left out by
    --data.recordings and session b vanished; a name no recording of the project has is refused in one line
    naming it and the closest recording, before any calibration."""
    project = _copy_project(uncalibrated_project, tmp_path / "project")
    config = RigProjectConfig(root=project, recordings=("walking01",), sessions=("a=walking01", "b=wavng02"), image_size=(1920, 1080))
    with pytest.raises(ValueError) as error:
        load_rig_project(config, progress=False)
    assert str(error.value) == f"--data.sessions b=wavng02: {project} has no recording 'wavng02'; the closest is 'waving02' (its recordings: walking01, waving02)"


def test_a_session_whose_recording_lacks_a_camera_is_named_with_the_way_out(uncalibrated_project, tmp_path):
    """Issue 52 defect 11: a session whose recording has no folder for one camera stopped with "view cam03 cannot
    be placed in the rig: it sees only 0 of the joints", naming neither the session nor the recording; the
    line names them, the camera they lack, and what to do."""
    project = _copy_project(uncalibrated_project, tmp_path / "project")
    shutil.rmtree(project / "walking01" / "cam03_json")
    config = RigProjectConfig(root=project, sessions=("a=waving02", "b=walking01"), image_size=(1920, 1080))  # walking01's first
    with pytest.raises(ValueError) as error:
        load_rig_project(config, progress=False)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith("session b (recordings walking01, as --data.sessions gives it): its rig cannot be recovered: view cam03 cannot be placed")
    assert message.endswith(
        "; recording walking01 has no detections of camera cam03; give every camera's detections, leave such a recording out"
        " (--data.recordings) or give it a calibration file"
    )
