"""`--train.eval-flip`: a finished run's command given again with it evaluates the final checkpoint again,
with test-time flip, and the report is what `Lifter3D.predict(..., flip=True)` gives on the test views."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from experiments import synthetic as synthetic_job
from jaxpose.training import evaluation
from jaxpose.serving import inference
from conftest import TRAINED_RUN_ARGS

pytestmark = [pytest.mark.trains]
METHOD = "Lifter, self-supervised (ours)"


def test_a_finished_run_is_evaluated_again_with_flip(trained_run, tmp_path):
    source, test = trained_run
    run_dir = tmp_path / "synthetic"
    shutil.copytree(source, run_dir)
    plain = json.loads((run_dir / "report.json").read_text())
    synthetic_job.main([*TRAINED_RUN_ARGS, "--run.run-dir", str(run_dir), "--train.eval-flip"])  # the run's own command
    flipped = json.loads((run_dir / "report.json").read_text())
    assert flipped["test_time_flip"] and not plain["test_time_flip"] and flipped["train_steps"] == plain["train_steps"]
    assert "Test-time flip" in (run_dir / "report.md").read_text()

    lifter = inference.load(run_dir)
    undistorted = test.undistorted()
    N, C, J, _ = test.samples.keypoints2d.shape
    keypoints, confidence = undistorted.samples.keypoints2d.reshape(N * C, J, 2), undistorted.samples.confidence.reshape(N * C, J)
    Ks = np.asarray(test.rigs.K)[test.samples.rig_index].reshape(N * C, 3, 3)
    target = evaluation.poses_in_views(test, test.samples.target3d).reshape(N * C, J, 3)
    valid = confidence[:, 0] > 0
    for report, flip in ((plain, False), (flipped, True)):
        poses = lifter.predict(keypoints, Ks, confidence, flip=flip)
        ours = evaluation.summarize(evaluation.compute_metrics(poses[valid], target[valid])[0])["overall"]["p_mpjpe"]
        assert ours == pytest.approx(report["results"][METHOD]["overall"]["p_mpjpe"], abs=0.01)
    assert flipped["results"][METHOD]["overall"]["p_mpjpe"] != plain["results"][METHOD]["overall"]["p_mpjpe"]
