"""experiments.label_bias: the body frame, the definition bias it measures, the relabelled training
sets, and the study end to end on the tiny Human3.6M fixture tree."""

import json

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from experiments import label_bias
from fixtures_real_data import H36M_SH_FILE_MOCAP, H36M_SUBJECTS, TINY_TRAINING, write_h36m_martinez_tree
from geometry_helpers import random_poses, random_rig
from help_text import assert_every_flag_documented
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.data.samples import Samples
from jaxpose.skeleton import H36M_16

J = H36M_16.num_joints


def _poses(seed: int, count: int = 64) -> np.ndarray:
    return random_poses(np.random.default_rng(seed), count, J).astype(np.float64)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_body_frames_are_rotations_that_turn_with_the_body(seed):
    poses = _poses(seed)
    frames = label_bias.body_frames(poses, H36M_16)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", frames, frames), np.broadcast_to(np.eye(3), frames.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-9)
    # x points from the right hip to the left one, z has no component along x and leans to the thorax.
    hips = poses[:, H36M_16.index("LHip")] - poses[:, H36M_16.index("RHip")]
    np.testing.assert_allclose(frames[..., 0], hips / np.linalg.norm(hips, axis=-1, keepdims=True), atol=1e-9)
    trunk = poses[:, H36M_16.index("Thorax")] - poses[:, H36M_16.index("Hip")]
    assert np.all(np.sum(frames[..., 2] * trunk, -1) > 0)
    # Turning and moving the poses turns the frames alike.
    rotation = Rotation.random(random_state=seed).as_matrix()
    moved = poses @ rotation.T + np.array([100.0, -2000.0, 50.0])
    np.testing.assert_allclose(label_bias.body_frames(moved, H36M_16), rotation @ frames, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_definition_bias_recovers_a_body_fixed_offset(seed):
    rng = np.random.default_rng(seed)
    truth = _poses(seed)
    offset = rng.normal(0, 80, (J, 3))
    labels = label_bias.moved_in_body(truth, label_bias.body_frames(truth, H36M_16), offset)
    taught = np.ones((len(truth), J), bool)
    bias = label_bias.definition_bias(labels, truth, taught, H36M_16)
    np.testing.assert_allclose(bias, offset - offset[:1], atol=1e-6)  # root-relative: no bias at the root
    # Frame-to-frame error with zero mean in the body frame (pairs of opposite errors in the body
    # frames of two poses, the root's included) does not move the estimate.
    half = len(truth) // 2
    frames = label_bias.body_frames(truth, H36M_16)
    in_body = rng.normal(0, 30, (half, J, 3))
    noise = np.concatenate([np.einsum("nij,nkj->nki", frames[:half], in_body), np.einsum("nij,nkj->nki", frames[half:], -in_body)])
    np.testing.assert_allclose(label_bias.definition_bias(labels + noise, truth, taught, H36M_16), bias, atol=1e-6)
    # A label that is not taught does not count, however wrong.
    garbage = labels.copy()
    garbage[:5, 3] += 1e5
    taught[:5, 3] = False
    np.testing.assert_allclose(label_bias.definition_bias(garbage, truth, taught, H36M_16), bias, atol=1e-6)


def _rigid_motion(rng: np.random.Generator, count: int) -> np.ndarray:
    """f64[count, J, 3]: one random body, turned and moved at random (a body whose joints stay put)."""
    body = rng.normal(0, 250, (J, 3))
    rotations = Rotation.random(count, random_state=rng.integers(2**31)).as_matrix()
    return np.einsum("nij,kj->nki", rotations, body) + rng.normal(0, 1000, (count, 1, 3))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_definition_map_moves_a_pose_onto_the_other_definitions(seed):
    """Labels that differ from the truth by a body-fixed offset: the map, estimated on some poses
    and applied in the body frames of the labels' own skeleton, gives the truth back on new poses."""
    rng = np.random.default_rng(seed)
    motion = _rigid_motion(rng, 80)
    offset = rng.normal(0, 60, (J, 3))
    labels = label_bias.moved_in_body(motion, label_bias.body_frames(motion, H36M_16), offset)
    taught = np.ones((40, J), bool)
    correction = label_bias.definition_map(labels[:40], motion[:40], taught, H36M_16)
    mapped = label_bias.moved_in_body(labels[40:], label_bias.body_frames(labels[40:], H36M_16), correction)
    np.testing.assert_allclose(mapped - mapped[:, :1], motion[40:] - motion[40:, :1], atol=1e-6)


def _labelled_set(truth: np.ndarray, labels: np.ndarray) -> MultiViewDataset:
    N = len(truth)
    rig = random_rig(np.random.default_rng(0), 2)
    rigs = jax.tree.map(lambda field: np.asarray(field)[None], rig)  # one rig of two views
    samples = Samples(
        keypoints2d=np.zeros((N, 2, J, 2), np.float32),
        confidence=np.ones((N, 2, J), np.float32),
        rig_index=np.zeros(N, np.int32),
        target3d=truth.astype(np.float32),
        pseudo3d=labels.astype(np.float32),
        pseudo3d_weight=np.ones((N, J), np.float32),
    )
    return MultiViewDataset(skeleton=H36M_16, rigs=rigs, samples=samples)


def test_relabelled_training_sets():
    rng = np.random.default_rng(3)
    truth = _poses(3)
    offset = rng.normal(0, 80, (J, 3))
    offset[0] = 0.0
    frames = label_bias.body_frames(truth, H36M_16)
    biased = label_bias.moved_in_body(truth, frames, offset)
    noise = rng.normal(0, 20, truth.shape)
    noise -= np.einsum("nij,kj->nki", frames, np.einsum("nij,nki->nkj", frames, noise - noise[:, :1]).mean(0))
    train = _labelled_set(truth, biased + noise)
    assert label_bias.relabelled("pseudo-labels", train) is train
    only_bias = label_bias.relabelled("definition bias only", train)
    np.testing.assert_allclose(only_bias.samples.pseudo3d, biased, atol=1e-2)
    removed = label_bias.relabelled("bias removed", train)
    np.testing.assert_allclose(removed.samples.pseudo3d, truth + noise, atol=1e-2)
    assert removed.samples.pseudo3d.dtype == np.float32 and removed.samples.pseudo3d_weight is train.samples.pseudo3d_weight
    with pytest.raises(ValueError, match="unknown label kind"):
        label_bias.relabelled("mocap", train)
    with pytest.raises(ValueError, match="3D ground truth"):
        label_bias.relabelled("bias removed", train.with_samples(target3d=None))


@pytest.mark.slow  # ~40 s: seven trainings; the study's parts are tested above, the whole with `pytest -m slow`
@pytest.mark.trains
def test_label_bias_study_end_to_end(tmp_path):
    # Like SH's "Spine", the 2D file's Spine is another mocap joint (here the thorax): a definition bias.
    sh_joints = tuple(13 if mocap == 12 else mocap for mocap in H36M_SH_FILE_MOCAP)
    write_h36m_martinez_tree(tmp_path / "h36m", sh_mocap_joints=sh_joints)
    run_dir = tmp_path / "study"
    argv = ["--preset", "cpu", "--data.data-dir", str(tmp_path / "h36m"), "--data.detections", "sh"]
    learning = ["--optimizer.warmup-steps", "0", "--train.epochs", "3"]  # the preset warms up for 800 steps
    text = label_bias.main(argv + H36M_SUBJECTS + TINY_TRAINING + learning + ["--run.run-dir", str(run_dir)])
    assert (run_dir / "label_bias.md").read_text() == text + "\n"
    for kind in label_bias.LABEL_KINDS:
        for terms, _ in label_bias.TERM_SETS:
            assert f"| {kind}, {terms} |" in text
    assert "| pseudo-labels, all four losses, output mapped to the mocap's joints |" in text
    assert "| Supervised twin (3D ground truth) |" in text and "| Input triangulation" in text
    lengths = next(line for line in text.splitlines() if line.startswith("| length |")).strip("| ").split(" | ")[1:]
    spine = H36M_16.index("Spine")
    assert float(lengths[spine]) > 50 and all(float(v) < 5 for i, v in enumerate(lengths) if i != spine)
    # The labels of both halves (all joints) come closer to the ground truth without the bias.
    for half in ("training", "test"):
        row = next(line for line in text.splitlines() if line.startswith(f"| {half} |")).strip("| ").split(" | ")
        assert float(row[2]) < float(row[1]) - 5, row

    def p_mpjpe(directory):  # the hook reaches training: the same seed on other labels, another lifter
        report = json.loads((run_dir / directory / "report.json").read_text())
        return report["results"][report["method"]]["overall"]["p_mpjpe"]

    assert p_mpjpe("pseudo-labels__L_in") != p_mpjpe("bias_removed__L_in")


def test_label_bias_help_and_refusals(capsys):
    with pytest.raises(SystemExit) as stop:
        label_bias.main(["--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert "those of --preset dev" in text
    lines = text[text.index("Presets (--preset NAME") :].splitlines()[1:7]
    presets, recipes = lines[0::2], lines[1::2]  # each preset's note, then its recipe made from its config
    assert [line.split()[0] for line in presets] == ["dev", "cpu", "paper"]
    assert all(line.endswith(f"(runs/label_bias_h36m_{line.split()[0]})") for line in presets)  # this study's run directories
    assert all(line.split()[0].startswith("width-") for line in recipes)
    assert_every_flag_documented(text, ["--data.data-dir", "--data.detections", "--run.run-dir", "--train.epochs"])
    with pytest.raises(SystemExit, match="leave --supervision self"):
        label_bias.main(["--supervision", "full"])
