"""The exported lifter (`python -m jaxpose.export`): ONNX run by onnxruntime and the `jax.export`
form, each against `Lifter3D.predict` on the shared tiny trained synthetic run."""

from __future__ import annotations

import json

import jax
import numpy as np
import onnx
import onnxruntime
import pytest

from help_text import assert_every_flag_documented
from jaxpose import export
from jaxpose.serving import inference

TOLERANCE_MM = 0.01


def _poses(test, count: int):
    """`count` single-view test poses (keypoints, K, confidence), with a missing joint whose
    coordinates are NaN and a pose whose root is missing among them."""
    N, C, J, _ = test.samples.keypoints2d.shape
    keypoints = test.samples.keypoints2d.reshape(N * C, J, 2)[:count].copy()
    confidence = test.samples.confidence.reshape(N * C, J)[:count].copy()
    K = np.asarray(test.rigs.K)[test.samples.rig_index].reshape(N * C, 3, 3)[:count].astype(np.float32)
    confidence[1, 5], keypoints[1, 5] = 0.0, np.nan
    confidence[2, 0] = 0.0
    confidence[0, 3] = 0.02  # below the run's score threshold (0.05, the default: the synthetic run records none)
    return keypoints, K, confidence


def _threshold(exported, run_dir) -> float:
    """The score threshold the export put in the graph: the run's (the synthetic run records none: the default), in the metadata."""
    threshold = json.loads(exported.with_suffix(".json").read_text())["min_confidence"]
    assert inference.load(run_dir).record.min_confidence is None and threshold == inference.DEFAULT_MIN_CONFIDENCE == 0.05
    return threshold


@pytest.fixture(scope="module")
def exported(trained_run, tmp_path_factory):
    output = tmp_path_factory.mktemp("export") / "lifter.onnx"
    export.main([str(trained_run[0]), "--output", str(output)])
    return output


def test_onnx_model_matches_predict_and_carries_the_joint_names(exported, trained_run, lifter):
    session = onnxruntime.InferenceSession(str(exported))
    threshold = _threshold(exported, trained_run[0])
    assert [i.name for i in session.get_inputs()] == list(export.INPUT_NAMES)
    for count in (3, 57):  # the batch axis is dynamic
        keypoints, K, confidence = _poses(trained_run[1], count)
        (poses,) = session.run(None, {"keypoints": keypoints, "K": K, "confidence": confidence})
        expected = lifter.predict(keypoints, K, confidence, min_confidence=threshold)
        assert poses.shape == (count, lifter.num_joints, 3)
        np.testing.assert_array_equal(np.isnan(poses).all((1, 2)), confidence[:, 0] < threshold)
        np.testing.assert_allclose(poses, expected, atol=TOLERANCE_MM, rtol=0)  # NaN rows compare equal
    properties = {p.key: json.loads(p.value) for p in onnx.load(str(exported)).metadata_props}
    assert properties["joint_names"] == list(lifter.joint_names) and properties["skeleton"] == lifter.skeleton.name
    assert json.loads(exported.with_suffix(".json").read_text())["joint_names"] == list(lifter.joint_names)


def test_jax_form_matches_predict(exported, trained_run, lifter):
    restored = jax.export.deserialize(exported.with_suffix(export.JAX_SUFFIX).read_bytes())
    keypoints, K, confidence = _poses(trained_run[1], 11)
    poses = np.asarray(restored.call(keypoints, K, confidence))
    np.testing.assert_allclose(poses, lifter.predict(keypoints, K, confidence, min_confidence=_threshold(exported, trained_run[0])), atol=TOLERANCE_MM, rtol=0)
    # The export takes the run's threshold (issue 41): only the poses with a score between 0 and it change.
    unthresholded = lifter.predict(keypoints, K, confidence)
    changed = ~np.isclose(poses, unthresholded, atol=TOLERANCE_MM, rtol=0, equal_nan=True).all((1, 2))
    low = ((confidence > 0) & (confidence < 0.05)).any(1)
    assert low[0] and changed.tolist() == low.tolist()


def test_errors_and_help(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    with pytest.raises(SystemExit, match="no checkpoints/"):
        export.main([str(tmp_path / "run"), "--output", str(tmp_path / "lifter.onnx")])
    with pytest.raises(SystemExit) as stop:
        export.main(["--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert_every_flag_documented(text, ["--output", "--onnx", "--min-confidence", "--overwrite"])
    assert "RUN_DIR" in text and "newest readable checkpoint" in text


def test_a_second_export_replaces_the_files_only_with_overwrite(trained_run, tmp_path):
    output = tmp_path / "lifter.onnx"
    export.main([str(trained_run[0]), "--output", str(output), "--no-onnx"])
    written = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(written) == ["lifter.jax_export", "lifter.json"]  # no temporary file left behind
    with pytest.raises(SystemExit, match=r"lifter\.json: exists; pass --overwrite"):
        export.main([str(trained_run[0]), "--output", str(output), "--no-onnx"])
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == written
    export.main([str(trained_run[0]), "--output", str(output), "--no-onnx", "--overwrite"])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(written)
    assert json.loads((tmp_path / "lifter.json").read_text()) == json.loads(written["lifter.json"])
