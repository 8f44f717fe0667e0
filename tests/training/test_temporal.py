"""The temporal lifter (issue 24): windows cut around samples, the network with a window, and sequence
prediction through `Lifter3D.predict`, `jaxpose.predict` and the exported forms."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import onnxruntime
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from detection_helpers import body25_from_coco, coco_from_h36m
from experiments import synthetic as synthetic_job
from jaxpose import export, predict
from jaxpose.serving import inference
from jaxpose.camera import Cameras
from jaxpose.model import ModelConfig
from jaxpose.data.dataset import MultiViewDataset, concatenate, consecutive_spans, window_rows
from jaxpose.data.samples import Samples
from jaxpose.layouts import to_skeleton
from jaxpose.model import LifterNetwork
from jaxpose.skeleton import H36M_17

TOLERANCE_MM = 0.01


@settings(max_examples=200, deadline=None)
@given(
    length=st.integers(1, 40),
    window=st.sampled_from([1, 3, 9, 27]),
    offset=st.integers(0, 100),
    data=st.data(),
)
def test_a_window_is_centred_on_its_frame_and_repeats_the_edge_frames(length, window, offset, data):
    position = data.draw(st.integers(0, length - 1))
    row = offset + position
    (rows,) = window_rows(np.array([row]), np.array([[offset, offset + length]]), window)
    half = window // 2
    assert len(rows) == window and rows[half] == row
    for k, got in enumerate(rows):
        wanted = row + k - half
        # Inside the stretch, the frame itself; beyond an end, that end's frame.
        assert got == min(max(wanted, offset), offset + length - 1)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("ab"), st.sampled_from("xy"), st.integers(0, 4)), min_size=1, max_size=30))
def test_stretches_break_at_a_new_subject_sequence_or_skipped_frame(steps):
    subject, sequence, frame = [], [], []
    current = 0
    for s, q, gap in steps:  # frame numbers advance by 1 + gap // 3 (a skipped frame now and then)
        current += 1 + gap // 3
        subject.append(s), sequence.append(q), frame.append(current)
    labels = {"subject": np.array(subject), "sequence": np.array(sequence), "frame": np.array(frame)}
    spans = consecutive_spans(labels)
    for i in range(len(frame)):  # the oracle: walk out from each row while the frames continue
        first = i
        while first > 0 and (subject[first - 1], sequence[first - 1], frame[first - 1] + 1) == (subject[first], sequence[first], frame[first]):
            first -= 1
        end = i + 1
        while end < len(frame) and (subject[end - 1], sequence[end - 1], frame[end - 1] + 1) == (subject[end], sequence[end], frame[end]):
            end += 1
        assert tuple(spans[i]) == (first, end)


def _recording_dataset(lengths=(7, 12), views=2, distorted=False) -> MultiViewDataset:
    """Frames of len(lengths) recordings (one rig each) whose 2D encodes (recording, frame, view, joint)."""
    rng = np.random.default_rng(0)
    J = H36M_17.num_joints
    rows = []
    for recording, length in enumerate(lengths):
        for frame in range(length):
            rows.append((recording, frame))
    N = len(rows)
    keypoints = rng.uniform(200, 800, (N, views, J, 2)).astype(np.float32)
    confidence = np.ones((N, views, J), np.float32)
    K = np.tile(np.array([[900.0, 0, 500], [0, 900, 500], [0, 0, 1]], np.float32), (len(lengths), views, 1, 1))
    R = np.tile(np.eye(3, dtype=np.float32), (len(lengths), views, 1, 1))
    t = np.tile(np.array([0, 0, 4000], np.float32), (len(lengths), views, 1)) + np.arange(views)[None, :, None] * 500
    dist = None
    if distorted:
        dist = np.zeros((len(lengths), views, 5), np.float32)
        dist[..., 0] = np.array([-0.2, 0.1])[: len(lengths), None]
    labels = {
        "subject": np.array([f"S{r}" for r, _ in rows]),
        "sequence": np.array(["walk"] * N),
        "frame": np.array([f for _, f in rows], np.int32),
    }
    return MultiViewDataset(
        skeleton=H36M_17,
        rigs=Cameras(K=K, R=R, t=t.astype(np.float32), dist=dist),
        samples=Samples(keypoints2d=keypoints, confidence=confidence, rig_index=np.array([r for r, _ in rows], np.int32), labels=labels),
    ).with_own_context()


def test_windows_of_a_thinned_split_are_the_full_rate_frames():
    every_frame = _recording_dataset()
    stride = 3
    kept = np.flatnonzero(every_frame.samples.labels["frame"] % stride == 0)
    thinned = every_frame.subset(kept)
    keypoints, confidence = thinned.windows(np.arange(len(thinned)), 9)
    assert keypoints.shape == (len(kept), 2, 9, H36M_17.num_joints, 2) and confidence.shape == keypoints.shape[:-1]
    np.testing.assert_array_equal(keypoints[:, :, 4], thinned.samples.keypoints2d)  # the centre is the sample itself
    for sample, row in enumerate(kept):
        recording = every_frame.samples.rig_index[row]
        same = np.flatnonzero(every_frame.samples.rig_index == recording)
        expected = np.clip(np.arange(row - 4, row + 5), same.min(), same.max())  # never another recording's frame
        np.testing.assert_array_equal(keypoints[sample], np.moveaxis(every_frame.samples.keypoints2d[expected], 0, 1))
    # Two parts with the same context, joined: the windows do not change.
    joined = concatenate([thinned.subset(np.arange(2)), thinned.subset(np.arange(2, len(thinned)))])
    np.testing.assert_array_equal(joined.windows(np.arange(len(joined)), 9)[0], keypoints)
    with pytest.raises(ValueError, match="temporal window of 3 frames needs"):
        without_context = dataclasses.replace(every_frame.samples, context_row=None, context_span=None)
        MultiViewDataset(every_frame.skeleton, every_frame.rigs, without_context).windows(np.arange(2), 3)


def test_undistorting_a_thinned_split_undistorts_its_windows_with_each_recording_rig():
    every_frame = _recording_dataset(distorted=True)
    kept = np.flatnonzero(every_frame.samples.labels["frame"] % 4 == 1)
    windows = every_frame.subset(kept).undistorted().windows(np.arange(len(kept)), 3)[0]
    oracle = every_frame.undistorted()  # every frame undistorted as a sample, through its own rig
    rows = window_rows(every_frame.samples.context_row[kept], every_frame.samples.context_span[kept], 3)
    np.testing.assert_allclose(windows, np.moveaxis(oracle.samples.keypoints2d[rows], 1, 2), atol=1e-3)


def test_a_window_of_one_frame_is_the_frame_network():
    frame = LifterNetwork(num_joints=17, width=32)
    temporal = LifterNetwork(num_joints=17, width=32, temporal_window=1)
    x = jax.random.normal(jax.random.key(1), (5, 17, 2))
    variables = frame.init(jax.random.key(0), x, train=False)
    assert jax.tree.structure(variables) == jax.tree.structure(temporal.init(jax.random.key(0), x, train=False))
    np.testing.assert_array_equal(frame.apply(variables, x, train=False), temporal.apply(variables, x, train=False))


def test_the_temporal_network_can_be_the_frame_network_on_the_centre_frame():
    """The frame network's function class is inside the temporal one: with the first layer reading only the
    centre frame of each triple and every temporal block's residual branch switched off (BatchNorm scale and
    bias 0), a window of 9 frames gives exactly the frame network's pose of the centre frame."""
    J, width = 17, 32
    frame = LifterNetwork(num_joints=J, width=width, dropout_rate=0.0)
    temporal = LifterNetwork(num_joints=J, width=width, dropout_rate=0.0, temporal_window=9)
    windows = jax.random.normal(jax.random.key(2), (6, 9, J, 2))
    frame_vars = frame.init(jax.random.key(0), windows[:, 4], train=False)
    perturbed = jax.tree.map(lambda v: v + 0.1 * jax.random.normal(jax.random.key(3), v.shape), frame_vars["params"])
    frame_vars = {"params": perturbed, "batch_stats": frame_vars["batch_stats"]}
    variables = jax.tree.map(jnp.copy, temporal.init(jax.random.key(1), windows, train=False))
    params, stats = dict(variables["params"]), dict(variables["batch_stats"])
    for name in frame_vars["params"]:
        params[name], stats[name] = frame_vars["params"][name], frame_vars["batch_stats"].get(name, {})
    first = frame_vars["params"]["DenseBlock_0"]["Dense_0"]["kernel"]  # [2J, width]
    zeros = jnp.zeros_like(first)
    params["DenseBlock_0"] = dict(params["DenseBlock_0"], Dense_0={"kernel": jnp.concatenate([zeros, first, zeros])})
    for name in ("TemporalBlock_1",):
        block = dict(params[name])
        block["DenseBlock_1"] = dict(block["DenseBlock_1"], BatchNorm_0={"scale": jnp.zeros(width), "bias": jnp.zeros(width)})
        params[name] = block
    got = temporal.apply({"params": params, "batch_stats": stats}, windows, train=False)
    np.testing.assert_allclose(got, frame.apply(frame_vars, windows[:, 4], train=False), atol=1e-4)


@pytest.fixture(scope="module")
def temporal_run(tmp_path_factory):
    """A tiny synthetic run with a window of 3 frames: (run directory, its test split)."""
    run_dir = tmp_path_factory.mktemp("run") / "temporal"
    synthetic_job.main(["--preset", "tiny", "--run.run-dir", str(run_dir), "--model.temporal-window", "3"])
    report = json.loads((run_dir / "report.json").read_text())
    assert report["config"]["model"]["temporal_window"] == 3
    return run_dir


def _sequence(count: int):
    """One person's sequence of `count` frames (smooth motion), with a missing joint and a frame whose root is missing."""
    rng = np.random.default_rng(5)
    base = rng.uniform(300, 700, (17, 2)).astype(np.float32)
    drift = np.linspace(0, 40, count, dtype=np.float32)[:, None, None]
    keypoints = base + drift + rng.normal(0, 2, (count, 17, 2)).astype(np.float32)
    confidence = np.ones((count, 17), np.float32)
    confidence[3, 7], keypoints[3, 7] = 0.0, np.nan
    confidence[5, 0] = 0.0
    K = np.array([[1000.0, 0, 500], [0, 1000, 500], [0, 0, 1]], np.float32)
    return keypoints, K, confidence


def test_sequence_prediction_lifts_each_frame_with_its_window(temporal_run):
    lifter = inference.load(temporal_run)
    keypoints, K, confidence = _sequence(12)
    poses = lifter.predict(keypoints, K, confidence)
    assert np.isnan(poses[5]).all() and np.isfinite(np.delete(poses, 5, 0)).all()
    clean = np.where(confidence[..., None] > 0, keypoints, 0.0)
    for frame in (0, 4, 11):  # an edge, the interior, the other edge: the window by hand
        rows = np.clip(np.arange(frame - 1, frame + 2), 0, 11)
        one = lifter.eval_step(lifter.variables, clean[rows][None], K[None], confidence[rows][None])[0]
        np.testing.assert_allclose(poses[frame], one, atol=1e-3)
    # A frame's pose depends on its neighbours (the network is temporal), not on frames outside its window.
    moved = keypoints.copy()
    moved[8, 5] += 30.0  # one joint: a translation of the whole frame would not change its root-relative input
    changed = lifter.predict(moved, K, confidence)
    assert np.abs(changed[7] - poses[7]).max() > 1e-3
    np.testing.assert_array_equal(changed[:7], poses[:7])


def test_exported_temporal_lifter_matches_predict(temporal_run, tmp_path):
    lifter = inference.load(temporal_run)
    output = tmp_path / "lifter.onnx"
    export.main([str(temporal_run), "--output", str(output)])
    keypoints, K, confidence = _sequence(12)
    expected = lifter.predict(keypoints, K, confidence)
    rows = window_rows(np.arange(12), np.array([[0, 12]] * 12), 3)
    inputs = {"keypoints": keypoints[rows], "K": np.repeat(K[None], 12, 0), "confidence": confidence[rows]}
    (onnx_poses,) = onnxruntime.InferenceSession(str(output)).run(None, inputs)
    np.testing.assert_allclose(onnx_poses, expected, atol=TOLERANCE_MM, rtol=0)
    restored = jax.export.deserialize(output.with_suffix(export.JAX_SUFFIX).read_bytes())
    np.testing.assert_allclose(np.asarray(restored.call(*inputs.values())), expected, atol=TOLERANCE_MM, rtol=0)
    assert json.loads(output.with_suffix(".json").read_text())["temporal_window"] == 3


def test_cli_lifts_an_npz_sequence_in_frame_order(temporal_run, tmp_path):
    lifter = inference.load(temporal_run)
    keypoints, K, confidence = _sequence(10)
    order = np.random.default_rng(0).permutation(10)  # written shuffled; image ids give the order
    path = tmp_path / "sequence.npz"
    np.savez(path, keypoints=keypoints[order], confidence=confidence[order], image_id=order)
    output = tmp_path / "poses.npz"
    args = ["--checkpoint", temporal_run, "--input", path, "--output", output, "--intrinsics", "1000", "1000", "500", "500"]
    poses = predict.main([str(a) for a in args])
    expected = lifter.predict(keypoints, K, confidence, image_size=None)
    np.testing.assert_allclose(poses, expected[order], atol=TOLERANCE_MM)
    with np.load(output) as written:
        np.testing.assert_array_equal(written["image_id"], order)


def test_a_temporal_window_must_be_a_power_of_three():
    with pytest.raises(ValueError, match="power of 3"):
        ModelConfig(temporal_window=5)


def test_cli_follows_one_person_through_an_openpose_folder(temporal_run, tmp_path):
    """Frames in frame-number order, an empty frame kept as a gap, the best-scoring of two people followed
    and the other written as null."""
    lifter = inference.load(temporal_run)
    keypoints, K, confidence = _sequence(6)
    confidence[5, 0] = 1.0  # every frame's root detected
    keypoints = np.nan_to_num(keypoints)
    body25 = body25_from_coco(coco_from_h36m(keypoints), 0.9)  # [6, 25, 3]
    folder = tmp_path / "openpose"
    folder.mkdir()
    bystander = body25[0].copy()
    bystander[:, 2] = 0.3  # a second, lower-scoring person in frame 1
    for frame in range(6):
        people = [] if frame == 3 else [body25[frame]] + ([bystander] if frame == 1 else [])
        document = {"version": 1.3, "people": [{"pose_keypoints_2d": p.ravel().tolist()} for p in people]}
        (folder / f"clip_{frame:012d}_keypoints.json").write_text(json.dumps(document))
    args = ["--checkpoint", temporal_run, "--input", folder, "--output", tmp_path / "poses.npz", "--intrinsics", "1000", "1000", "500", "500"]
    args += ["--format", "body25"]  # 75 values per person: BODY_25 or BODY_25B, which the count cannot tell apart
    poses = predict.main([str(a) for a in args])
    assert poses.shape == (6, 17, 3)  # five followed poses and the bystander, in file order
    assert np.isnan(poses[2]).all() and np.isfinite(np.delete(poses, 2, 0)).all()
    sequence, scores = to_skeleton("body25", H36M_17, body25[..., :2], body25[..., 2])
    scores[3] = 0.0  # the empty frame: a frame of missing joints in its neighbours' windows
    expected = lifter.predict(sequence, K, scores)
    np.testing.assert_allclose(np.delete(poses, 2, 0), np.delete(expected, 3, 0), atol=TOLERANCE_MM)


def test_mpi_inf_3dhp_lifts_each_stretch_of_valid_frames_as_its_own_sequence(temporal_run, tmp_path):
    from experiments import mpi_inf_3dhp
    from fixtures_real_data import write_mpi_inf_3dhp_test_set
    from jaxpose.datasets.mpi_inf_3dhp import camera_intrinsics, load_mpi_inf_3dhp_test

    K = {name: camera_intrinsics(name) for name in ("TS1", "TS5")}
    data = write_mpi_inf_3dhp_test_set(tmp_path / "3dhp", {"TS1": "v7.3", "TS5": "v5"}, K=K)
    argv = ["--run-dir", temporal_run, "--data-dir", data.root, "--sequences", "TS1", "TS5", "--out-dir", tmp_path / "out", "--no-progress"]
    report = mpi_inf_3dhp.main([str(a) for a in argv])
    test = load_mpi_inf_3dhp_test(data.root, ("TS1", "TS5"), progress=False)
    lifter = inference.load(temporal_run)
    spans = consecutive_spans({"sequence": test.sequence, "frame": test.frame})
    assert len(np.unique(spans, axis=0)) > 2  # two sequences, and gaps at invalid frames
    expected = np.concatenate(
        [lifter.predict(test.keypoints2d[a:b], intrinsics=test.K[a:b]) for a, b in np.unique(spans, axis=0).tolist()]
    )
    mpjpe = np.linalg.norm(expected - (test.univ3d - test.univ3d[:, :1]), axis=-1).mean()
    assert report["by_activity"]["overall"]["mpjpe"] == pytest.approx(mpjpe, abs=0.01)
