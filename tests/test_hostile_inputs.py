"""A hostile or careless user's folders (issue 42): nothing read from a user's folder runs code, no command
deletes or writes what it was not asked to, and what it refuses is still there afterwards.

Each case here failed before its fix: a crafted pickle in a project's cache ran at the next load; a run
directory pointed at a folder of other files was emptied by --run.overwrite (or silently filled);
`jaxpose.predict` wrote into its own input folder; two recordings of `jaxpose.reconstruct` wrote one file.
"""

from __future__ import annotations

import ast
import contextlib
import dataclasses
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
from jaxpose.rig.project import RigProjectConfig, load_rig_project
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
    """A run folder with a study's summary and a nested run (as experiments.search and ablation leave them):
    --run.overwrite removes the run's own entries and keeps the others."""
    from jaxpose.training.run_directory import RunDirectory, prepare_run_dir

    run_dir = tmp_path / "run"
    files = RunDirectory(run_dir)
    prepare_run_dir(_experiment(run_dir, overwrite=False))
    files.metrics.write_text("{}\n")
    (files.checkpoints / "100").mkdir(parents=True)
    files.report_md.write_text("old")
    (run_dir / "search.md").write_text("summary")
    prepare_run_dir(_experiment(run_dir / "supervised", overwrite=False))
    prepare_run_dir(_experiment(run_dir, overwrite=True))
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.json", "plots", "run.json", "search.md", "supervised"]
    assert (run_dir / "supervised" / "run.json").is_file()


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

    project = tmp_path / "project"
    shutil.copytree(small_project, project, ignore=shutil.ignore_patterns(".jaxpose_cache"))
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
    metres and a score threshold of 0.2 is read back so by reconstruct (flags left at their defaults), and
    predict takes its threshold; a flag given that differs is said in one line and used."""
    from jaxpose.serving.inference import score_threshold
    from jaxpose.rig.project import recorded_settings, with_recorded_settings
    from jaxpose.training.run_directory import RunRecord, prepare_run_dir, read_record, write_record

    trained = RigProjectConfig(
        root=tmp_path / "project", calibration=tmp_path / "rig.toml", calibration_unit="m", sync="auto", frame_offsets=("cam02=3",),
        min_confidence=0.2, image_size=(1920, 1080), validation_fraction=0.3, train_stride=2,
    )
    run_dir = tmp_path / "run"
    prepare_run_dir(_experiment(run_dir, overwrite=False))
    write_record(run_dir, RunRecord(min_confidence=0.2, layout="coco17", project=recorded_settings(trained, "coco17")))
    record = read_record(run_dir / "checkpoints")  # the checkpoints folder names the same run
    applied, notes = with_recorded_settings(RigProjectConfig(), record.project, "run.json")
    assert notes == []
    expected = dataclasses.replace(trained, skeleton="coco17", validation_fraction=0.2, train_stride=1)  # the split is not carried
    assert applied == expected
    overridden, notes = with_recorded_settings(RigProjectConfig(sync="given", min_confidence=0.3), record.project, "run.json")
    assert overridden.min_confidence == 0.3 and overridden.sync == "auto"  # sync "given" is the default: the run's wins
    assert notes == ["--data.min-confidence 0.3 differs from the run's 0.2 (run.json): using 0.3"]
    assert score_threshold(run_dir, None) == 0.2 and score_threshold(tmp_path / "elsewhere", None) == 0.05
    assert score_threshold(run_dir, 0.05) == 0.05
    assert "--min-confidence 0.05 differs from the run's 0.2" in capsys.readouterr().err


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
    import json

    project = tmp_path / "project"
    shutil.copytree(small_project, project, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    frame = sorted(project.glob("*/cam02_json/*.json"))[5]
    content = json.loads(frame.read_text())
    content["people"][0]["pose_keypoints_2d"][27:29] = [far, far / 2]  # joint 9 (left wrist, COCO-17)
    frame.write_text(json.dumps(content))
    data = load_rig_project(RigProjectConfig(root=project), progress=False)
    for part in (data.train, data.validation):
        assert np.isfinite(np.asarray(part.samples.keypoints2d)).all() and np.isfinite(np.asarray(part.samples.confidence)).all()
    assert (np.asarray(data.train.samples.keypoints2d) < 3000).all()


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
    import json

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
    project = tmp_path / "project"
    shutil.copytree(small_project, project, ignore=shutil.ignore_patterns(".jaxpose_cache"))
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
    import json

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
    shutil.copytree(small_project, root / "project", ignore=shutil.ignore_patterns(".jaxpose_cache"))
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
