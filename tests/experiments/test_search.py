"""The recipe search (`experiments.search`): the grid, the ranking and its agreement with the truth, and
two tiny variants on the embedded example project, trained once and read back on a second start."""

from __future__ import annotations

import json

import numpy as np
import pytest

from experiments import search
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project


def test_the_grid_is_every_combination_of_the_axes():
    variants = search.grid([["model.width", "256", "512"], ["train.augment.drop", "0", "0.1", "0.2"]])
    assert len(variants) == 6
    assert variants[1].name == "model.width=256, train.augment.drop=0.1"
    assert variants[1].flags == ("--model.width", "256", "--train.augment.drop", "0.1")
    assert search.grid([]) == [search.Variant(search.BASE, ())]
    with pytest.raises(SystemExit, match="without dashes"):
        search.grid([["--model.width", "256"]])


def _run(metric: float, truth: float | None) -> dict:
    return {search.SELECTION_METRIC: metric, "p_mpjpe": truth, "samples": 100, "samples_per_s": 10.0, "wall_time_s": 1.0}


def test_ranking_by_reprojection_and_its_agreement_with_the_truth():
    rows = {  # reprojection px / P-MPJPE mm, two seeds each: the reprojection swaps the truly best two
        "a": [_run(10.0, 42.0), _run(12.0, 42.0)],  # means 11 / 42
        "b": [_run(10.0, 40.0), _run(10.0, 40.0)],  # 10 / 40
        "c": [_run(9.0, 41.0), _run(9.0, 41.0)],  # 9 / 41
        "d": [_run(20.0, 50.0), _run(20.0, 50.0)],  # 20 / 50
    }
    ranked = search.ranking(rows)
    assert ranked["order"] == ["c", "b", "a", "d"] and ranked["selected"] == "c" and ranked["best_by_truth"] == "b"
    assert ranked["selection_cost_mm"] == pytest.approx(1.0)
    # true ranks along the reprojection order: 2, 1, 3, 4 -> one discordant pair of six
    assert ranked["spearman"] == pytest.approx(1 - 6 * 2 / (4 * 15)) and ranked["kendall"] == pytest.approx(4 / 6)
    table = search.report_table(rows, [0, 1], 1000)
    assert "| 1 | c | 9.0 (9.0 / 9.0) | 41.0 (41.0 / 41.0) | 2 |" in table and "Spearman's rho +0.80" in table
    without_truth = search.ranking({name: [_run(run[search.SELECTION_METRIC], None) for run in runs] for name, runs in rows.items()})
    assert without_truth["selected"] == "c" and "spearman" not in without_truth


@pytest.mark.trains
def test_two_tiny_variants_on_the_example_project(tmp_path, monkeypatch):
    project = write_rig_project(tmp_path / "project", ExampleProjectConfig(recordings=2, frames_per_recording=240))
    run_dir = tmp_path / "search"
    flags = [
        "--dataset", "rig", "--data.root", str(project), "--run.run-dir", str(run_dir), "--train.batch-size", "32",
        "--train.epochs", "2", "--train.max-samples", "640", "--train.eval-every", "0", "--run.no-progress",
        "--run.plot-samples", "0", "--run.no-tensorboard", "--vary", "model.width", "32", "64",
    ]  # fmt: skip
    text = search.main(flags)
    result = json.loads((run_dir / "search.json").read_text())
    assert set(result["runs"]) == {"model.width=32", "model.width=64"}
    for name, width in (("model.width=32", 32), ("model.width=64", 64)):
        (run,) = result["runs"][name]
        assert run["samples"] == 640 and np.isfinite(run[search.SELECTION_METRIC]) and np.isfinite(run["p_mpjpe"])
        config = json.loads((run_dir / f"{name}/seed0/config.json").read_text())
        assert config["model"]["width"] == width and config["train"]["max_samples"] == 640
    ranked = result["ranking"]
    assert ranked["selected"] == ranked["order"][0] and abs(ranked["spearman"]) == pytest.approx(1.0)
    assert "Selected without ground truth" in text and (run_dir / "search.md").read_text() == text

    def no_training(*args, **kwargs):
        raise AssertionError("a finished variant was trained again")

    monkeypatch.setattr(search, "run", no_training)
    assert search.main(flags) == text
