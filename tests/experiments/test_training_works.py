"""Training works: the shared tiny run's lifter is far better than the mean pose, and the main job
(README's `python -m experiments.synthetic`) keeps the accuracy docs/main-job.md documents."""

import json
import re

import pytest

import paths
from experiments import synthetic

pytestmark = [pytest.mark.trains]

LIFTER, MEAN_POSE = "Lifter, self-supervised (ours)", "Mean pose (baseline)"


def _p_mpjpe(run_dir) -> dict[str, float]:
    """{method: P-MPJPE in mm over the whole test split} of a run's report."""
    report = json.loads((run_dir / "report.json").read_text())
    return {method: summary["overall"]["p_mpjpe"] for method, summary in report["results"].items()}


def test_the_shared_runs_lifter_is_at_least_twice_better_than_the_mean_pose(trained_run):
    # tests/conftest.py's run: 150 steps of the tiny preset, on its test subjects (never trained on).
    errors = _p_mpjpe(trained_run[0])
    assert errors[LIFTER] <= errors[MEAN_POSE] / 2, errors


def documented_main_job_p_mpjpe() -> float:
    """The self-supervised row's "All" column of docs/main-job.md's table (mm)."""
    text = (paths.REPO / "docs" / "main-job.md").read_text()
    row = re.search(rf"^\| {re.escape(LIFTER)} \|(.*)\|$", text, re.MULTILINE)
    assert row, f"docs/main-job.md holds no '{LIFTER}' row"
    return float(row.group(1).split("|")[-1])


@pytest.mark.slow
def test_the_main_job_stays_within_ten_percent_of_its_documented_p_mpjpe(tmp_path):
    documented = documented_main_job_p_mpjpe()
    synthetic.main(["--run.run-dir", str(tmp_path / "run")])
    measured = _p_mpjpe(tmp_path / "run")[LIFTER]
    assert abs(measured - documented) <= 0.1 * documented, (measured, documented)
