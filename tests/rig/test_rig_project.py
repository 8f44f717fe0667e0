"""Training on your own rig (`experiments.rig`, `jaxpose.rig.project`): the example project end to
end, the person choice, frame offsets, the ground-truth-free measures, and every refusal."""

import dataclasses
import json
import shutil

import jax.numpy as jnp
import numpy as np
import pytest
from help_text import assert_every_flag_documented

from experiments import rig as rig_job
from jaxpose import predict
from jaxpose.training import self_consistency
from jaxpose import camera
from jaxpose.camera import Cameras, projection_matrices
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.formats.errors import DataFormatError
from jaxpose.rig.people import choose_person
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.timeline import estimate_offsets
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project
from jaxpose.formats.trc import read_trc
import paths

SMALL = ExampleProjectConfig(recordings=2, frames_per_recording=240)


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    return write_rig_project(tmp_path_factory.mktemp("rig") / "project", SMALL)


@pytest.fixture()
def project_copy(project, tmp_path):
    """A copy to break."""
    copy = tmp_path / "project"
    shutil.copytree(project, copy, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    return copy


def _ring_cameras(count: int) -> Cameras:
    """`count` cameras 4 m from the origin, 1.5 m up, looking at it."""
    K, R, t = [], [], []
    for c in range(count):
        angle = 2 * np.pi * c / count + 0.3
        centre = np.array([4000 * np.cos(angle), 4000 * np.sin(angle), 1500.0])
        z = -centre / np.linalg.norm(centre)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        rotation = np.stack([x, np.cross(z, x), z])
        K.append([[1000.0, 0, 500], [0, 1000.0, 500], [0, 0, 1]])
        R.append(rotation)
        t.append(-rotation @ centre)
    return Cameras(K=np.array(K, np.float32), R=np.array(R, np.float32), t=np.array(t, np.float32))


def _pixels(cameras: Cameras, points: np.ndarray) -> np.ndarray:
    """World points [N, J, 3] -> pixels [N, C, J, 2]."""
    return np.asarray(camera.project(cameras[None], jnp.asarray(points, jnp.float32)[:, None]))


@pytest.mark.trains
def test_example_project_trains_resumes_and_lifts(project, tmp_path):
    run_dir = tmp_path / "run"
    flags = [
        "--data.root", str(project), "--data.sync", "auto", "--run.run-dir", str(run_dir), "--model.width", "64",
        "--train.batch-size", "32", "--train.epochs", "2", "--train.max-steps", "20", "--train.eval-every", "10",
        "--train.eval-samples", "50",
        "--run.no-progress", "--run.plot-samples", "1", "--run.no-tensorboard",
    ]  # fmt: skip
    report = rig_job.main(flags)
    truth = json.loads((project / "example_truth.json").read_text())
    camera = truth["desynchronized_camera"]
    # The out-of-sync camera was found (the walking recording moves enough) and the passer-by met.
    assert any(f"{camera} +{truth['desync_offset_frames']} (estimated" in note for note in report["notes"])
    assert report["camera_names"] == truth["cameras"]
    # Ground truth over the joints it shares with the detector's skeleton (COCO-17 + the pelvis root).
    assert report["joint_names"][0] == "pelvis" and len(report["joint_names"]) == 18
    ours = report["results"]["Lifter, self-supervised (ours)"]["overall"]
    assert np.isfinite(ours["p_mpjpe"]) and ours["count"] > 0
    for name in self_consistency.METRICS:
        values = report["ground_truth_free"][name]
        assert np.isfinite(values["overall"]) and len(values["per_camera"]) == 4
    evaluations = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines() if "eval_" in line]
    assert [r["step"] for r in evaluations] == [10, 20]
    assert {"eval_p_mpjpe", "eval_disagreement_mm", "eval_reprojection_px", "eval_triangulation_p_mpjpe_mm"} <= set(evaluations[-1])
    assert "Without ground truth" in (run_dir / "report.md").read_text()
    # Resuming the finished run trains no further step and reports the same.
    again = rig_job.main(flags)
    assert again["train_steps"] == 20
    assert again["results"]["Lifter, self-supervised (ours)"]["overall"]["p_mpjpe"] == pytest.approx(ours["p_mpjpe"], abs=1e-4)
    # predict takes the run as it takes any other: one camera's OpenPose folder, in the detector's layout.
    recording = sorted(p for p in project.iterdir() if p.is_dir() and not p.name.startswith("."))[0]
    out = tmp_path / "poses.trc"
    poses = predict.main(["--checkpoint", str(run_dir), "--input", str(recording / "cam01_json"), "--output", str(out),
                          "--intrinsics", str(project / "calibration.toml"), "cam01", "--fps", "50"])  # fmt: skip
    trc = read_trc(out)
    assert poses.shape[1] == 18 and trc.marker_names[0] == "pelvis" and trc.units == "m"


def test_help_documents_every_data_flag(capsys):
    with pytest.raises(SystemExit) as stop:
        rig_job.main(["--help"])
    assert stop.value.code == 0
    flags = ["--data." + field.name.replace("_", "-") for field in dataclasses.fields(RigProjectConfig)]
    assert_every_flag_documented(capsys.readouterr().out, flags)


def test_the_person_the_views_agree_on():
    """Two people: the subject in every instant, a passer-by in some, listed first at random, and in
    one camera the passer-by alone for a while (the subject occluded there)."""
    rng = np.random.default_rng(0)
    cameras = _ring_cameras(4)
    N, J = 60, 17
    subject = rng.normal(0, 300, (N, J, 3)) + [0, 0, 1000]
    passer = rng.normal(0, 300, (N, J, 3)) + [1500, 800, 1000]
    subject[:, 0], passer[:, 0] = [0, 0, 1000], [1500, 800, 1000]
    seen_subject, seen_passer = _pixels(cameras, subject), _pixels(cameras, passer)
    keypoints = np.zeros((N, 4, 2, J, 2), np.float32)
    confidence = np.zeros((N, 4, 2, J), np.float32)
    first = rng.random((N, 4)) < 0.5
    for n in range(N):
        for c in range(4):
            s, p = (1, 0) if first[n, c] else (0, 1)
            keypoints[n, c, s] = seen_subject[n, c] + rng.normal(0, 2, (J, 2))
            confidence[n, c, s] = 1
            if n < 15:
                keypoints[n, c, p] = seen_passer[n, c] + rng.normal(0, 2, (J, 2))
                confidence[n, c, p] = 1
    keypoints[:10, 3], confidence[:10, 3] = 0, 0
    keypoints[:10, 3, 0], confidence[:10, 3, 0] = seen_passer[:10, 3], 1  # camera 3 sees only the passer-by
    choice = choose_person(np.asarray(projection_matrices(cameras)), keypoints, confidence)
    kept = choice.confidence > 0
    assert np.abs(choice.keypoints - seen_subject)[kept].max() < 15  # always the subject
    assert kept[10:].all() and not kept[:10, 3].any() and kept[:10, :3].all()
    assert choice.instants_with_choice == 15 and choice.views_without_match == 10


def _moving_person(cameras: Cameras, frames: int, offsets: np.ndarray, rng):
    """One person walking about, seen by every camera with `offsets` (camera c's frame f shows instant f + offsets[c])."""
    t = np.arange(frames) / 50.0
    body = rng.normal(0, 250, (17, 3))
    path = np.stack([1500 * np.sin(0.7 * t), 1200 * np.sin(0.5 * t + 1), 1000 + 0 * t], 1)
    points = body[None] + path[:, None] + 100 * np.sin(3 * t)[:, None, None] * rng.normal(size=(1, 17, 3))
    pixels = _pixels(cameras, points) + rng.normal(0, 2, (frames, len(offsets), 17, 2))
    per_camera = []
    for c, offset in enumerate(offsets):
        instants = np.arange(max(0, offset), frames + min(0, offset))
        per_camera.append((instants - offset, pixels[instants, c], np.ones((len(instants), 17))))
    return [list(values) for values in zip(*per_camera)]


@pytest.mark.parametrize("calibrated", [True, False])
def test_frame_offsets_are_recovered(calibrated):
    cameras = _ring_cameras(4)
    truth = np.array([0, 0, 3, 0])
    frames, keypoints, confidence = _moving_person(cameras, 400, truth, np.random.default_rng(1))
    P = np.asarray(projection_matrices(cameras), np.float64) if calibrated else None
    estimate = estimate_offsets(frames, keypoints, confidence, P, max_offset=6)
    np.testing.assert_array_equal(estimate.offsets, truth)
    assert estimate.reliable


def test_a_still_person_gives_an_unreliable_sync():
    cameras = _ring_cameras(3)
    rng = np.random.default_rng(2)
    still = rng.normal(0, 250, (1, 17, 3)) + [0, 0, 1000]
    pixels = _pixels(cameras, np.repeat(still, 200, 0)) + rng.normal(0, 2, (200, 3, 17, 2))
    estimate = estimate_offsets([np.arange(200)] * 3, [pixels[:, c] for c in range(3)], [np.ones((200, 17))] * 3,
                                np.asarray(projection_matrices(cameras), np.float64), max_offset=4)  # fmt: skip
    assert not estimate.reliable and estimate.doubt == "the person hardly moves between frames"


@pytest.mark.parametrize("calibrated", [True, False])
def test_a_camera_at_half_the_frame_rate_is_named_not_taken_for_a_still_person(calibrated):
    """Issue 42 case 10: a 25 fps camera beside 50 fps ones (its own frames numbered 0, 1, 2, ...) fits no integer
    offset; the estimate says so and names it, rather than blaming the person's motion."""
    cameras = _ring_cameras(4)
    frames, keypoints, confidence = _moving_person(cameras, 400, np.zeros(4, int), np.random.default_rng(3))
    frames[2], keypoints[2], confidence[2] = np.arange(200), keypoints[2][::2], confidence[2][::2]
    P = np.asarray(projection_matrices(cameras), np.float64) if calibrated else None
    estimate = estimate_offsets(frames, keypoints, confidence, P, max_offset=6, camera_names=["a", "b", "c", "d"])
    assert not estimate.reliable
    assert estimate.doubt.startswith("camera c has 200 frames against the others' 400: another frame rate?")


def test_ground_truth_free_measures_against_an_oracle(project):
    data = load_rig_project(RigProjectConfig(root=project, frame_offsets=("cam03=3",)), progress=False)
    from jaxpose.training import evaluation, pseudo_labelling
    from jaxpose.training.config import PseudoLabelConfig

    test = pseudo_labelling.label(data.validation, PseudoLabelConfig(method="ransac"))
    truth, _ = evaluation.ground_truth_in_views(test)
    exact = self_consistency.self_consistency(truth, test, test.samples.pseudo3d, test.samples.pseudo3d_weight > 0)
    assert exact["disagreement_mm"]["overall"] < 1e-2  # one pose seen from every camera
    # The reprojection of the true pose is the detector's error (a few px), that of the true pose
    # against the triangulation the triangulation's error.
    assert 1 < exact["reprojection_px"]["overall"] < 15 and exact["triangulation_p_mpjpe_mm"]["overall"] < 40
    # Depth guessed wrong in one view: that view disagrees and reprojects worse, the others less so.
    flattened = truth.copy()
    flattened[:, 1, :, 2] *= 0.2
    worse = self_consistency.self_consistency(flattened, test, test.samples.pseudo3d, test.samples.pseudo3d_weight > 0)
    assert worse["disagreement_mm"]["per_camera"][1] > 50 > exact["disagreement_mm"]["per_camera"][1]
    assert worse["reprojection_px"]["per_camera"][1] > 2 * exact["reprojection_px"]["per_camera"][1]
    assert worse["reprojection_px"]["per_camera"][0] == pytest.approx(exact["reprojection_px"]["per_camera"][0])
    # A broken lifter (issue 42 case 5): tests/test_hostile_inputs.py.


def _raises(match, root, **config):
    with pytest.raises((DataFormatError, ValueError), match=match):
        load_rig_project(RigProjectConfig(root=root, **config), progress=False)


def test_refusals_name_the_file_and_field(project_copy, tmp_path):
    recordings = sorted(p for p in project_copy.iterdir() if p.is_dir() and not p.name.startswith("."))
    # A camera of the calibration with no detections in any recording.
    for index, recording in enumerate(recordings):
        shutil.move(recording / "cam04_json", tmp_path / f"spare{index}")
    _raises(r"calibration.toml: expected a detection folder for each of its cameras .*cam04.* no detections", project_copy)
    for index, recording in enumerate(recordings):
        shutil.move(tmp_path / f"spare{index}", recording / "cam04_json")
    # Detections of a camera the calibration lacks.
    recording = recordings[0]
    shutil.copytree(recording / "cam01_json", recording / "cam09_json")
    _raises(r"calibration.toml: expected a camera for every name .*lack \['cam09'\]", project_copy)
    shutil.rmtree(recording / "cam09_json")
    # A calibration whose unit makes the rig implausible.
    _raises(r"calibration.toml.*--data.calibration-unit", project_copy, calibration_unit="mm")
    # A JSON frame that is not OpenPose's.
    frame = sorted((recording / "cam01_json").glob("*.json"))[5]
    frame.write_text(json.dumps({"persons": []}))
    _raises(rf"{frame.name}.*people", project_copy)
    frame.unlink()
    # A recording with fewer than two cameras.
    for camera in ("cam02_json", "cam03_json", "cam04_json"):
        shutil.rmtree(recording / camera)
    _raises(rf"{recording.name}: expected detections of at least 2 cameras", project_copy)


def test_a_detections_npz_is_checked_as_calibration_checks_it(tmp_path):
    """A recording's detections.npz goes through the one reader of the format: a NaN confidence is
    refused in one line naming the file and the field."""
    recording = tmp_path / "project" / "trial"
    recording.mkdir(parents=True)
    confidence = np.ones((30, 2, 17), np.float32)
    confidence[4, 1, 3] = np.nan
    np.savez(recording / "detections.npz", keypoints=np.zeros((30, 2, 17, 2), np.float32), confidence=confidence,
             camera_names=np.array(["a", "b"]), skeleton=np.array("coco17"))  # fmt: skip
    with pytest.raises(DataFormatError) as error:
        load_rig_project(RigProjectConfig(root=tmp_path / "project"), progress=False)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith(f"{recording / 'detections.npz'}, field 'confidence': expected finite values >= 0; found NaN")


def test_a_body25_project_needs_its_layout_named(tmp_path):
    root = write_rig_project(tmp_path / "body25", dataclasses.replace(SMALL, layout="body25", recordings=1, frames_per_recording=60))
    _raises(r"75 values per person are OpenPose BODY_25 or BODY_25B .*--data.skeleton body25", root)
    data = load_rig_project(RigProjectConfig(root=root, skeleton="body25"), progress=False)
    assert data.layout == "body25" and data.train.skeleton.joint_names[0] == "MidHip"


def test_a_project_without_calibration_or_image_size_is_refused(tmp_path):
    root = write_rig_project(tmp_path / "uncalibrated", dataclasses.replace(SMALL, recordings=1, frames_per_recording=40, desync_camera=-1))
    (root / "calibration.toml").unlink()
    _raises(r"--data.image-size W H", root)


@pytest.mark.slow  # ~28 s of calibration; measured on Human3.6M in docs/rig.md, calibration itself in test_calibration.py
@pytest.mark.trains
def test_a_project_without_calibration_recovers_the_rig(tmp_path):
    """No calibration file: the rig is recovered from the recordings (jaxpose.calibrate), and the
    ground truth is brought into its world frame for evaluation."""
    root = write_rig_project(tmp_path / "uncalibrated", dataclasses.replace(SMALL, recordings=1, frames_per_recording=400, desync_camera=-1))
    reference = read_rig_calibration(root / "calibration.toml")
    (root / "calibration.toml").unlink()
    data = load_rig_project(RigProjectConfig(root=root, image_size=(1920, 1080), recovery_frames=120), progress=False)
    recovered = data.recovered_calibration
    assert recovered is not None and np.median(recovered.reprojection_median_px) < 10
    # The ground truth, turned into the recovered world, has the triangulation's orientation in every
    # camera: root-relative and up to the recovered rig's scale error (the limb prior's misfit: N-MPJPE's
    # scale alignment), the two agree to the triangulation's error, not to a rotation's.
    from jaxpose.training import evaluation, pseudo_labelling
    test = pseudo_labelling.label(data.validation)
    truth, valid = evaluation.ground_truth_in_views(test)
    triangulated = evaluation.poses_in_views(test, test.samples.pseudo3d)
    labelled = valid & (test.samples.pseudo3d_weight > 0).all(-1)[:, None]
    assert labelled.sum() > 100 and reference.camera_names == data.camera_names
    scale = (triangulated * truth).sum((-2, -1), keepdims=True) / (triangulated**2).sum((-2, -1), keepdims=True)
    assert np.median(np.linalg.norm(truth - scale * triangulated, axis=-1).mean(-1)[labelled]) < 30
    # A reconstruction of a run trained on this rig (its recovered_cameras.json, as experiments.rig writes
    # it) reads the prepared project the run was trained on: every instant, in the same world.
    from jaxpose.formats.camera_file import save_cameras
    from jaxpose.reconstruction import recording
    from jaxpose.training.run_directory import RunDirectory

    run = RunDirectory(tmp_path / "run")
    run.path.mkdir()
    save_cameras(run.recovered_cameras, {"rig": (list(recovered.camera_names), recovered.cameras)})
    config = RigProjectConfig(root=root, image_size=(1920, 1080), recovery_frames=120)
    every = recording.load_every_instant(config, run, progress=False)
    assert every.prepared == data.prepared.replace("prepared and written to", "read from")
    assert len(every.instants) == len(data.train) + len(data.validation)
    np.testing.assert_array_equal(every.instants.rigs.R, data.validation.rigs.R)
    # Another rig in the run's file (not the one the cache holds): prepared in that rig's world instead.
    moved = dataclasses.replace(recovered.cameras, t=np.asarray(recovered.cameras.t) + 100.0)
    save_cameras(run.recovered_cameras, {"rig": (list(recovered.camera_names), moved)})
    elsewhere = recording.load_every_instant(config, run, progress=False)
    assert elsewhere.prepared.startswith("prepared and written") and elsewhere.recordings[0].calibration == str(run.recovered_cameras)


def test_ground_truth_for_some_recordings_serves_evaluation_only(project_copy):
    from jaxpose.training import evaluation
    recordings = sorted(p for p in project_copy.iterdir() if p.is_dir() and not p.name.startswith("."))
    (recordings[0] / "ground_truth.npz").unlink()
    data = load_rig_project(RigProjectConfig(root=project_copy, frame_offsets=("cam03=3",)), progress=False)
    assert data.train.samples.target3d is None  # no supervised twin on partial ground truth
    _, valid = evaluation.ground_truth_in_views(data.validation)
    with_truth = data.validation.samples.labels["recording"] != recordings[0].name
    assert valid[with_truth].any() and not valid[~with_truth].any()


SHARED_FORMATS = paths.FORMATS


@pytest.mark.skipif(not SHARED_FORMATS.is_dir(), reason="needs ../shared/data/formats (real sample files)")
def test_the_real_pose2sim_demo_as_a_rig_project(tmp_path):
    """Pose2Sim's demo as it is: 4 cameras of OpenPose BODY_25B JSON (a second person in two of them),
    cameras named "cam_01" in its calibration (metres) and "cam01_json" on disk.  The person the views
    agree on, triangulated, is the one Pose2Sim itself triangulated (its TRC, in OpenSim's y-up axes):
    25 mm apart at the median joint."""
    from jaxpose.training import pseudo_labelling
    from jaxpose.training.config import PseudoLabelConfig

    root = tmp_path / "demo"
    shutil.copytree(SHARED_FORMATS / "openpose-json" / "pose2sim_demo_balancing_body25b", root / "balancing")
    shutil.copy(SHARED_FORMATS / "pose2sim-calib-toml" / "pose2sim_demo_Calib_qualisys.toml", root / "Calib_qualisys.toml")
    _raises(r"75 values per person are OpenPose BODY_25 or BODY_25B", root)
    data = load_rig_project(RigProjectConfig(root=root, skeleton="body25b", validation_fraction=0.5), progress=False)
    summary = data.recordings[0]
    assert summary.instants == 20 and summary.instants_with_choice == 20 and data.camera_names == ("cam01", "cam02", "cam03", "cam04")
    labelled = pseudo_labelling.label(data.train, PseudoLabelConfig(method="ransac"))
    trc = read_trc(SHARED_FORMATS / "trc" / "pose2sim_demo_BalancingTrial_0-100.trc")
    names = [name for name in trc.marker_names if name in labelled.skeleton.joint_names]
    joints = [labelled.skeleton.index(name) for name in names]
    rows = trc.markers[labelled.samples.labels["frame"]][:, [trc.marker_names.index(name) for name in names]]  # row f: frame f
    theirs = 1000.0 * np.stack([rows[..., 2], rows[..., 0], rows[..., 1]], axis=-1)  # OpenSim's (Y, Z, X) -> z-up mm
    error = np.linalg.norm(labelled.samples.pseudo3d[:, joints] - theirs, axis=-1)[labelled.samples.pseudo3d_weight[:, joints] > 0]
    assert len(names) == 20 and len(error) > 150 and np.median(error) < 40, np.median(error)


def test_messy_projects_load(project_copy):
    """A camera that never sees anybody, a recording without one camera and with its own jaxpose camera file
    of the cameras it has, CAMERA=N offsets for a camera only some recordings have, and a crowd of
    detections in one frame."""
    from jaxpose.formats.calibration_files import read_rig_calibration
    from jaxpose.formats.camera_file import save_cameras

    first, second = sorted(p for p in project_copy.iterdir() if p.is_dir() and not p.name.startswith("."))
    for frame in (first / "cam02_json").glob("*.json"):
        frame.write_text(json.dumps({"version": 1.3, "people": []}))
    rig = read_rig_calibration(project_copy / "calibration.toml").select(["cam01", "cam02", "cam03"], "test")
    save_cameras(first / "cameras.json", {"rig": (list(rig.camera_names), rig.cameras)}, comment="this recording's own")
    shutil.rmtree(first / "cam04_json")
    crowd = sorted((second / "cam01_json").glob("*.json"))[10]
    frame = json.loads(crowd.read_text())
    frame["people"] = frame["people"] * 7
    crowd.write_text(json.dumps(frame))
    data = load_rig_project(RigProjectConfig(root=project_copy, frame_offsets=("cam03=3", "cam04=0")), progress=False)
    assert data.camera_names == ("cam01", "cam02", "cam03", "cam04")
    by_name = {r.name: r for r in data.recordings}
    assert by_name[first.name].cameras == ("cam01", "cam02", "cam03") and by_name[first.name].calibration.endswith("cameras.json")
    in_first = data.train.samples.labels["recording"] == first.name
    assert not (data.train.samples.confidence[in_first][:, 1:2] > 0).any()  # cam02 never saw anybody
    assert not (data.train.samples.confidence[in_first][:, 3] > 0).any()  # no cam04 in this recording
    assert (data.train.samples.confidence[~in_first] > 0).any((0, 2)).all()


def test_a_lost_marker_costs_its_instant_not_the_report(project):
    from jaxpose.training import evaluation
    from jaxpose.data.ground_truth import ground_truth_joints

    data = load_rig_project(RigProjectConfig(root=project, frame_offsets=("cam03=3",)), progress=False)
    test = data.validation
    target = test.samples.target3d.copy()
    target[0, 0] = np.nan  # the root lost in one instant
    target[1, 5] = np.nan  # another joint lost in another
    _, valid_before = evaluation.ground_truth_in_views(test)
    test = test.with_samples(target3d=target)
    joints = ground_truth_joints(test)
    assert len(joints) == test.skeleton.num_joints  # both still evaluated where known
    truth, valid = evaluation.ground_truth_in_views(test)
    assert valid_before[:2].any()  # the two instants were evaluated before the loss
    assert not valid[:2].any()  # without a root (or any joint), the instant is dropped
    np.testing.assert_array_equal(valid[2:], valid_before[2:])  # and nothing else
    summary = evaluation.evaluate_poses(truth, truth, None, valid)["overall"]
    assert summary["mpjpe"] == 0.0 and summary["count"] == valid.sum()


def test_the_rig_loader_is_given_the_runs_progress_bars_and_no_window():
    # The rig loader shows progress: the run's setting reaches it (every entry point that takes an
    # Experiment's loader: cli.main, ablations, searches).  It prepares every instant, so a temporal
    # window is cut from them (test_rig_loading) and is no option of loading: one cache for every lifter.
    calls = []
    experiment = dataclasses.replace(rig_job.EXPERIMENT, load_splits=lambda data, **settings: calls.append((data, settings)))
    config = dataclasses.replace(
        rig_job.CPU,
        model=dataclasses.replace(rig_job.CPU.model, temporal_window=9),
        run=dataclasses.replace(rig_job.CPU.run, progress=False),
    )
    experiment.loader(config)(config.data)
    experiment.loader()(config.data)
    assert calls == [(config.data, {"progress": False}), (config.data, {})]


_ONE_STEP = ["--model.width", "16", "--train.batch-size", "16", "--train.max-steps", "1", "--train.eval-samples", "20",
             "--run.no-progress", "--run.plot-samples", "0", "--run.no-tensorboard"]  # fmt: skip


def _prepared(root):
    return {p.name: p.stat().st_ino for p in (root / ".jaxpose_cache").iterdir() if p.name.startswith("prepared-")}


@pytest.mark.slow  # two one-step runs and a reconstruction, 25-90 s on 2 cores (by their load)
@pytest.mark.trains
def test_training_reconstruction_and_training_again_share_one_prepared_project(project_copy, tmp_path, capsys):
    """Issue 41: `experiments.rig`, then `jaxpose.reconstruct` (every instant, as "validation"), then
    `experiments.rig` again on one project: the second and third read the prepared project the first
    wrote and prepare nothing; no command removes it."""
    from jaxpose import reconstruct

    root = str(project_copy)
    rig_job.main(["--data.root", root, "--run.run-dir", str(tmp_path / "run"), *_ONE_STEP])
    first = capsys.readouterr().err
    assert "prepared and written to the cache" in first and "people chosen" in first
    prepared = _prepared(project_copy)
    assert len(prepared) == 1
    reconstruct.main(["--checkpoint", str(tmp_path / "run"), "--data.root", root, "--output", str(tmp_path / "motion"),
                      "--fps", "50", "--no-progress"])  # fmt: skip
    second = capsys.readouterr().err
    rig_job.main(["--data.root", root, "--run.run-dir", str(tmp_path / "again"), "--data.validation-fraction", "0.3", *_ONE_STEP])
    third = capsys.readouterr().err
    (folder,) = prepared
    for log in (second, third):
        assert f"prepared project read from the cache {project_copy / '.jaxpose_cache' / folder}" in log
        assert "people chosen" not in log and "recordings read" not in log and "prepared and written" not in log
    assert _prepared(project_copy) == prepared
    assert not [p for p in project_copy.glob("*/**/.jaxpose_cache")]


_READ_ONLY_RUN = """
import sys
from experiments import rig
from jaxpose import reconstruct
project, cache, run, motion = sys.argv[1:5]
rig.main(["--data.root", project, "--data.cache-dir", cache, "--run.run-dir", run, *sys.argv[5:]])
reconstruct.main(["--checkpoint", run, "--data.root", project, "--output", motion, "--fps", "50", "--no-progress"])
rig.main(["--data.root", project, "--run.run-dir", run + "_in_memory", *sys.argv[5:]])
"""


@pytest.mark.slow  # two one-step runs and a reconstruction in a child process, 30-100 s on 2 cores (by their load)
@pytest.mark.trains
def test_a_read_only_project_trains_and_reconstructs_with_a_cache_folder_given(project_copy, tmp_path):
    """A project on a read-only file system (a read-only bind mount where the suite runs as root, else the
    files' write permissions removed): `experiments.rig --data.cache-dir DIR` prepares into DIR,
    `jaxpose.reconstruct` (the run records the folder) reads it from there, and without a cache folder
    the project is prepared in memory; the project is left as it was."""
    import os
    import subprocess
    import sys

    before = sorted((str(p.relative_to(project_copy)), p.stat().st_mtime_ns) for p in project_copy.rglob("*"))
    command = [sys.executable, "-c", _READ_ONLY_RUN, str(project_copy), str(tmp_path / "cache"), str(tmp_path / "run"),
               str(tmp_path / "motion"), *_ONE_STEP]  # fmt: skip
    if os.geteuid() == 0:
        mount = f"mount --bind -o ro {project_copy} {project_copy} && exec \"$@\""
        probe = subprocess.run(["unshare", "-m", "sh", "-c", f"{mount}", "sh", "true"], capture_output=True)
        if probe.returncode:
            pytest.skip(f"running as root without a read-only bind mount (unshare: {probe.stderr.decode().strip()})")
        command = ["unshare", "-m", "sh", "-c", mount, "sh", *command]
    else:
        for path in [project_copy, *project_copy.rglob("*")]:
            path.chmod(path.stat().st_mode & ~0o222)
    done = subprocess.run(command, capture_output=True, text=True, cwd=os.getcwd(), timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    log = done.stderr
    assert f"prepared and written to the cache {tmp_path / 'cache'}" in log
    assert log.count(f"prepared project read from the cache {tmp_path / 'cache'}") == 1  # the reconstruction
    assert "cannot be written" in log and "prepared in memory" in log  # the run without --data.cache-dir
    assert (tmp_path / "motion" / "report.json").is_file() and (tmp_path / "cache" / "parsed").is_dir()
    assert sorted((str(p.relative_to(project_copy)), p.stat().st_mtime_ns) for p in project_copy.rglob("*")) == before
