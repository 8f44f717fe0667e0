"""End to end on a tiny configuration: the main job runs, and a resumed run equals an uninterrupted one."""

import dataclasses
import json

import jax
import numpy as np
import pytest

from experiments import synthetic
from jaxpose.training.experiment import TrainConfig
from jaxpose.training.run_directory import prepare_run_dir
from jaxpose.training.loop import train
from jaxpose.training.stream import TrainingStream
from jaxpose.training import pseudo_labelling
from jaxpose.model import ModelConfig

pytestmark = [pytest.mark.trains]

# The tiny preset on 2 training subjects (400 samples) and 1 test subject.
TINY_ARGS = [
    "--preset", "tiny",
    "--train.epochs", "2",
    "--train.batch-size", "64",
    "--train.log-every", "5",
    "--data.generator.num-train-subjects", "2",
    "--data.generator.num-test-subjects", "1",
]


def _tiny_config(run_dir, max_steps=0, window=1):
    tiny = synthetic.TINY
    return dataclasses.replace(
        tiny,
        data=synthetic.SyntheticData(dataclasses.replace(tiny.data.generator, num_train_subjects=2, num_test_subjects=1)),
        model=dataclasses.replace(tiny.model, temporal_window=window),
        train=TrainConfig(batch_size=32, epochs=2, max_steps=max_steps, log_every=4, checkpoint_every=3),
        run=dataclasses.replace(tiny.run, run_dir=run_dir),
    )


def _train(config):
    splits = synthetic.load_splits(config.data)
    train_set = pseudo_labelling.label(splits.train)
    state, _ = train(config, TrainingStream.of(config, train_set), prepare_run_dir(config))
    return jax.device_get(state)


# A temporal lifter fed windows of 9 frames: the frame lifter's resume is checked bit for bit, killed at
# any point, by tests/experiments/test_fault_tolerance.py, and the step is the same with windows in the batch.
# The second and third runs read the first one's programs from the tests' compilation cache, as a resumed command does.
@pytest.mark.parametrize("window", [9])
def test_resumed_training_matches_uninterrupted_training(tmp_path, window):
    full = _train(_tiny_config(tmp_path / "full", window=window))
    total = int(full.step)
    assert total == 2 * (400 // 32)
    _train(_tiny_config(tmp_path / "resumed", max_steps=total // 2, window=window))
    resumed = _train(_tiny_config(tmp_path / "resumed", window=window))  # same run dir: continues from step total//2
    assert int(resumed.step) == total
    for a, b in zip(jax.tree.leaves(full.params), jax.tree.leaves(resumed.params)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    for a, b in zip(jax.tree.leaves(full.batch_stats), jax.tree.leaves(resumed.batch_stats)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    # The resumed run's log continues where the first attempt stopped.
    steps = [json.loads(line)["step"] for line in (tmp_path / "resumed" / "metrics.jsonl").read_text().splitlines()]
    assert steps == sorted(steps) and steps[-1] == total


def test_main_job_writes_the_run_directory(trained_run):
    """The shared tiny run (tests/conftest.py: the main job's tiny preset, 150 steps)."""
    run_dir = trained_run[0]
    report = json.loads((run_dir / "report.json").read_text())
    plots = ("plots/loss_curves.png", "plots/gradient_shares.png", "plots/gt_vs_prediction.png")
    for name in ("config.json", "metrics.jsonl", "report.json", "report.md", *plots):
        assert (run_dir / name).exists(), name
    # Each term's share of the gradient w.r.t. the lifter output is logged (on every logged line:
    # the step measures them on those steps only) and reported.
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    for line in (record for record in records if "loss" in record):
        assert abs(sum(line[key] for key in line if key.startswith("grad_share_")) - 1.0) < 1e-4, line["step"]
    record = [record for record in records if "loss" in record][-1]  # the last training step's line
    assert record["step"] == report["train_steps"]
    shares = [record[f"grad_share_{term}"] for term in ("input_triangulation", "reprojection", "consistency", "output_triangulation")]
    assert abs(sum(shares) - 1.0) < 1e-4 and all(share > 0 for share in shares)
    assert report["final_gradient_shares"] == pytest.approx(dict(zip(("input_triangulation", "reprojection", "consistency", "output_triangulation"), shares)))
    report_md = (run_dir / "report.md").read_text()
    assert "P-MPJPE (mm) per joint" in report_md and "Share of each term in the gradient" in report_md
    assert len(report["results"]["Lifter, self-supervised (ours)"]["per_joint"]["p_mpjpe"]) == 17
    rows = report["results"]
    assert set(rows) == {"Lifter, self-supervised (ours)", "Input triangulation (multi-view, reference)", "Mean pose (baseline)"}
    for summary in rows.values():
        assert set(summary["groups"]) <= {"walking", "turning", "sitting", "crouching", "reaching", "waving", "gesturing", "bending"}
        assert np.isfinite(summary["overall"]["p_mpjpe"])
    # The input triangulation of mildly noisy detections is far better than a constant pose.
    assert rows["Input triangulation (multi-view, reference)"]["overall"]["mpjpe"] < 0.5 * rows["Mean pose (baseline)"]["overall"]["mpjpe"]
    assert "| Method |" in (run_dir / "report.md").read_text()


def test_a_run_directory_refuses_a_different_config(tmp_path):
    config = _tiny_config(tmp_path / "run")
    prepare_run_dir(config)
    (tmp_path / "run" / "checkpoints" / "3").mkdir(parents=True)  # a committed checkpoint: a run to resume
    changed = dataclasses.replace(config, model=ModelConfig(width=32))
    with pytest.raises(SystemExit, match="different config"):
        prepare_run_dir(changed)
    prepare_run_dir(dataclasses.replace(changed, run=dataclasses.replace(changed.run, overwrite=True)))


def test_ablation_configurations_switch_the_paper_terms(tmp_path):
    from experiments import ablation

    base = _tiny_config(tmp_path)
    configs = ablation.ablation_configs(base)
    weights = [tuple(getattr(c.loss, t) for t in ablation.TERMS) for _, c in configs]
    assert weights == [(1, 0, 0, 0), (0, 1, 0, 0), (1, 1, 0, 0), (1, 1, 0.001, 0), (1, 1, 0.001, 0.01)]
    assert len({c.run.run_dir for _, c in configs}) == 5 and all(c.run.run_dir.parent == tmp_path for _, c in configs)


def test_twin_comparison_reports_both_rows_and_the_triangulation(tmp_path):
    from experiments import ablation

    text = ablation.main(["--dataset", "synthetic", "--rows", "twin", *TINY_ARGS, "--train.epochs", "1", "--run.run-dir", str(tmp_path)])
    labels = [line.split("|")[1].strip() for line in text.splitlines()[:6] if line.startswith("| ") and "---" not in line]
    assert labels[1:] == [ablation.SELF_LABEL, ablation.SUPERVISED_LABEL, "Input triangulation (multi-view, reference)"]
    assert json.loads((tmp_path / "supervised" / "config.json").read_text())["loss"]["supervision"] == "full"
    own = json.loads((tmp_path / "5_input_reprojection_consistency_output" / "config.json").read_text())
    assert own["loss"]["supervision"] == "self" and own["loss"]["consistency"] > 0
    assert "P-MPJPE (mm) per joint" in (tmp_path / "comparison.md").read_text()


@pytest.mark.slow
def test_ablation_runs_the_five_loss_configurations(tmp_path):
    from experiments import ablation

    table = ablation.main(["--dataset", "synthetic", *TINY_ARGS, "--train.epochs", "1", "--run.run-dir", str(tmp_path)])
    rows = [line for line in table.split("\n\n")[0].splitlines() if line.startswith("| L_")]  # the summary table
    assert [row.split("|")[1].strip() for row in rows] == [label for label, _ in ablation.CONFIGURATIONS]
    config = json.loads((tmp_path / "2_reprojection" / "config.json").read_text())
    assert config["loss"]["input_triangulation"] == 0.0 and config["loss"]["reprojection"] == 1.0
    assert ablation.SUPERVISED_LABEL in table and (tmp_path / "comparison.md").exists()


def _tensorboard_scalars(directory) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(step, value)] of every event file under `directory`, read from the TFRecord framing
    (u64 length, u32 crc, Event proto, u32 crc) with tensorboardX's own Event message."""
    from tensorboardX.proto.event_pb2 import Event

    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(directory.rglob("events.out.tfevents.*")):
        data, offset = path.read_bytes(), 0
        while offset < len(data):
            length = int.from_bytes(data[offset : offset + 8], "little")
            event = Event.FromString(data[offset + 12 : offset + 12 + length])
            offset += 12 + length + 4
            for value in event.summary.value:
                scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_periodic_evaluation_and_tensorboard_curves(trained_run):
    """--train.eval-every logs the current model's test errors while training, to metrics.jsonl and
    TensorBoard; over the whole test split, its last value is the report's (the final checkpoint).  The
    shared tiny run (tests/conftest.py) is evaluated every 4 of its 150 steps, on its whole test split."""
    run_dir = trained_run[0]
    report = json.loads((run_dir / "report.json").read_text())
    assert len(trained_run[1]) <= TrainConfig().eval_samples  # the whole test split: not thinned
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    evaluations = [r for r in records if "eval_p_mpjpe" in r]
    total = report["train_steps"]
    assert [r["step"] for r in evaluations] == [*range(4, total, 4), total]
    final = report["results"]["Lifter, self-supervised (ours)"]["overall"]
    assert evaluations[-1]["eval_p_mpjpe"] == pytest.approx(final["p_mpjpe"], abs=1e-3)
    assert evaluations[-1]["eval_mpjpe"] == pytest.approx(final["mpjpe"], abs=1e-3)
    assert (run_dir / "plots" / "periodic_evaluation.png").exists()
    scalars = _tensorboard_scalars(run_dir / "tensorboard")
    for tag in ("train/loss", "train/learning_rate", "train/samples_per_s", "train/grad_share_reprojection"):
        assert [step for step, _ in scalars[tag]] == [r["step"] for r in records if "loss" in r], tag
    assert scalars["eval/eval_p_mpjpe"] == [(r["step"], pytest.approx(r["eval_p_mpjpe"], rel=1e-6)) for r in evaluations]
