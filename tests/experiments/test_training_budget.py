"""The training budget (jaxpose.training.stream.training_budget) and the stream of its batches: --train.max-samples shortens the run and
its schedules by thinning every epoch, a resume continues it, --train.epochs lifts a preset's cap, and a
batch larger than the data is refused before the run directory is written."""

import dataclasses
import json
import threading

import jax
import numpy as np
import pytest

from experiments import cli, synthetic
from jaxpose.training.experiment import TrainConfig
from jaxpose.training.run_directory import check_resumable, prepare_run_dir
from jaxpose.training.loop import train
from jaxpose.training.stream import TrainingStream, training_budget
from jaxpose.training import parallel, pseudo_labelling
from jaxpose.training.config import OptimizerConfig
from jaxpose.data.dataset import training_indices
from jaxpose.training.step import output_triangulation_start_step


def test_without_a_binding_cap_the_budget_is_every_sample_each_epoch():
    for cap in (0, 10**9):
        budget = training_budget(1000, TrainConfig(batch_size=64, epochs=3, max_samples=cap))
        assert (budget.steps_per_epoch, budget.total_steps, budget.capped) == (15, 45, False)


def test_a_cap_thins_every_epoch_and_keeps_the_epochs():
    # Issue 33's project (Human3.6M's seven subjects as a rig project): 30 epochs of 2,860 steps at batch 128.
    budget = training_budget(2_860 * 128, TrainConfig(batch_size=128, epochs=30, max_samples=2_300_000))
    assert budget.full_steps_per_epoch == 2_860 and budget.epochs == 30
    assert budget.steps_per_epoch == 2_300_000 // (128 * 30) == 598
    assert budget.total_steps * 128 <= 2_300_000 < (budget.total_steps + 30) * 128
    assert budget.note().startswith("6.3 of 30 epochs-worth of samples (2,296,320 samples: 30 epochs of 598 of 2,860 batches each)")
    assert budget.note().endswith("the cap 2,300,000 of --train.max-samples")


def test_a_cap_below_one_batch_per_epoch_and_a_batch_larger_than_the_data_are_one_line():
    with pytest.raises(SystemExit, match=r"^error: --train.max-samples 100 is below one batch per epoch \(--train.batch-size 64 x --train.epochs 3 = 192\)"):
        training_budget(1000, TrainConfig(batch_size=64, epochs=3, max_samples=100))
    with pytest.raises(SystemExit, match=r"^error: --train.batch-size 4096 is larger than the training set \(500 samples\); choose at most 500$"):
        training_budget(500, TrainConfig(batch_size=4096))


def _tiny(run_dir, **train):
    tiny = synthetic.TINY
    return dataclasses.replace(
        tiny,
        data=synthetic.SyntheticData(dataclasses.replace(tiny.data.generator, num_train_subjects=2, num_test_subjects=1)),
        optimizer=OptimizerConfig(schedule="cosine", warmup_steps=2),
        train=TrainConfig(**{"batch_size": 32, "epochs": 2, "log_every": 1, "checkpoint_every": 3} | train),
        run=dataclasses.replace(tiny.run, run_dir=run_dir, tensorboard=False),
    )


@pytest.fixture(scope="module")
def labelled():
    return pseudo_labelling.label(synthetic.load_splits(_tiny(None).data).train)


def _stream(labelled, rows=None, **train) -> TrainingStream:
    return TrainingStream.of(_tiny(None, **train), labelled, rows)


def test_the_capped_stream_is_each_epochs_first_batches_and_resumes_anywhere(labelled):
    stream = _stream(labelled, batch_size=32, epochs=3, max_samples=32 * 3 * 5)
    budget = stream.budget
    assert (budget.full_steps_per_epoch, budget.steps_per_epoch) == (12, 5)
    full = dict(zip(range(36), (indices for _, indices in training_indices(len(labelled), 32, 0))))
    mesh = parallel.data_mesh(1)
    batches = list(stream.batches(mesh, 0, budget.total_steps))
    assert [step for step, _ in batches] == list(range(budget.total_steps))
    for step, batch in batches:
        epoch, position = divmod(step, 5)
        np.testing.assert_array_equal(np.asarray(batch.keypoints2d), labelled.batch(full[epoch * 12 + position]).keypoints2d)
    for start in (3, 5, 9):  # mid-epoch, an epoch's first step, an epoch's last step
        [(got_step, batch)] = list(stream.batches(mesh, start, start + 1))
        epoch, position = divmod(start, 5)
        assert got_step == start
        np.testing.assert_array_equal(np.asarray(batch.keypoints2d), labelled.batch(full[epoch * 12 + position]).keypoints2d)


def test_training_on_some_rows_draws_the_batches_of_their_copy(labelled):
    # The runner leaves out samples with too few usable views as `rows` instead of a copy
    # (a memory-mapped training set stays on disk): the batches must be those of the copy.
    samples = np.flatnonzero(np.arange(len(labelled)) % 7 != 3)
    from_rows = _stream(labelled, samples, batch_size=32, epochs=2, max_samples=32 * 2 * 4)
    from_copy = _stream(labelled.subset(samples), batch_size=32, epochs=2, max_samples=32 * 2 * 4)
    assert from_rows.budget == from_copy.budget
    mesh, total = parallel.data_mesh(1), from_rows.budget.total_steps
    for (step, batch), (copy_step, copy_batch) in zip(from_rows.batches(mesh, 2, total), from_copy.batches(mesh, 2, total), strict=True):
        assert step == copy_step
        for field in ("keypoints2d", "confidence", "pseudo3d", "pseudo3d_weight"):
            np.testing.assert_array_equal(np.asarray(getattr(batch, field)), np.asarray(getattr(copy_batch, field)))


def test_the_stream_raises_what_went_wrong_making_a_batch_and_stops_its_thread_when_left(labelled, monkeypatch):
    stream = _stream(labelled, batch_size=32, epochs=3)
    mesh = parallel.data_mesh(1)
    before = threading.active_count()
    batches = stream.batches(mesh, 0, stream.budget.total_steps)
    next(batches)
    batches.close()  # a loop that stops early (Ctrl-C, a diverged loss) leaves no thread behind
    assert threading.active_count() == before
    broken = dataclasses.replace(stream, rows=np.arange(len(labelled)) + 5)  # 5 rows past the data set's end
    with pytest.raises(IndexError):
        for _ in broken.batches(mesh, 0, broken.budget.total_steps):
            pass
    assert threading.active_count() == before


def _metrics(run_dir) -> list[dict]:
    records = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in r.items() if k != "samples_per_s"} for r in records]


@pytest.mark.trains
def test_the_cap_shortens_the_schedule_and_a_resume_across_it_matches(tmp_path, labelled):
    # 400 samples at batch 32: 12 full steps per epoch; the cap 320 allows 5 per epoch, 10 in all.
    config = _tiny(tmp_path / "whole", max_samples=320)
    state, _ = train(config, TrainingStream.of(config, labelled), prepare_run_dir(config))
    records = _metrics(tmp_path / "whole")
    assert int(state.step) == 10 and [r["step"] for r in records] == list(range(1, 11))
    assert [r["epoch"] for r in records][4::5] == [1.0, 2.0]
    # The output triangulation comes on for the last 10% of the shortened run, not of the 24 uncapped steps.
    switch = output_triangulation_start_step(config.loss, 10)
    assert switch == 9 != output_triangulation_start_step(config.loss, 24)
    assert [r["output_triangulation_weight"] > 0 for r in records] == [step > switch for step in range(1, 11)]
    # The learning rate decays over the 10 steps: the last step's is near the end of the decay, where
    # the schedule of the 24 uncapped steps would still be above half the peak.
    assert records[-1]["learning_rate"] == pytest.approx(float(config.optimizer.learning_rate_schedule(10)(9)))
    assert records[-1]["learning_rate"] < 0.05 * config.optimizer.learning_rate < 0.1 * float(config.optimizer.learning_rate_schedule(24)(9))
    # Stopped at step 4 (--train.max-steps, not part of the run's identity) and resumed: the same run.
    stopped = _tiny(tmp_path / "resumed", max_samples=320, max_steps=4)
    train(stopped, TrainingStream.of(stopped, labelled), prepare_run_dir(stopped))
    resumed_config = _tiny(tmp_path / "resumed", max_samples=320)
    resumed, _ = train(resumed_config, TrainingStream.of(resumed_config, labelled), prepare_run_dir(resumed_config))
    assert _metrics(tmp_path / "resumed") == records
    for a, b in zip(jax.tree.leaves(jax.device_get(state.params)), jax.tree.leaves(jax.device_get(resumed.params))):
        np.testing.assert_array_equal(a, b)
    # Another cap is another run: its directory is not resumed with it.
    with pytest.raises(SystemExit, match="different config"):
        check_resumable(_tiny(tmp_path / "resumed", max_samples=640))


def test_a_presets_cap_is_a_value_like_any_other():
    """Issue 41: a config means what its fields say; --train.epochs on the command line no longer lifts the cap."""
    capped = dataclasses.replace(synthetic.TINY, train=dataclasses.replace(synthetic.TINY.train, max_samples=2048))
    presets = {"tiny": capped}

    def parsed(*argv):
        return cli.parse(synthetic.EXPERIMENT, list(argv), "test", presets=presets).train

    assert parsed().max_samples == 2048
    assert (parsed("--train.epochs", "5").epochs, parsed("--train.epochs", "5").max_samples) == (5, 2048)
    assert (parsed("--train.epochs", "5", "--train.max-samples", "0").epochs, parsed("--train.max-samples=0").max_samples) == (5, 0)
    assert parsed("--train.epochs=5", "--train.max-samples", "4096").max_samples == 4096
    assert parsed("--train.max_samples", "0").max_samples == 0


def test_a_batch_larger_than_the_data_is_refused_before_the_run_directory_is_written(tmp_path):
    run_dir = tmp_path / "run"
    tiny = ["--preset", "tiny", "--run.run-dir", str(run_dir)]
    with pytest.raises(SystemExit, match=r"^error: --train.batch-size 4096 is larger than the training set \(1000 samples\)"):
        synthetic.main([*tiny, "--train.batch-size", "4096"])
    assert not run_dir.exists()  # nothing for the corrected rerun to be compared with
    check_resumable(cli.parse(synthetic.EXPERIMENT, [*tiny, "--train.batch-size", "500"], "test"))


def test_a_start_that_left_no_checkpoint_does_not_block_another_config(tmp_path):
    config = _tiny(tmp_path / "run")
    prepare_run_dir(config)  # config.json, as a start that failed before its first checkpoint leaves it
    changed = _tiny(tmp_path / "run", batch_size=16)
    assert prepare_run_dir(changed).path == tmp_path / "run"
    assert json.loads((tmp_path / "run" / "config.json").read_text())["train"]["batch_size"] == 16
    (tmp_path / "run" / "checkpoints" / "3").mkdir(parents=True)  # a committed checkpoint: a run to resume
    with pytest.raises(SystemExit, match="different config"):
        check_resumable(config)


def test_a_test_split_larger_than_the_evaluation_cap_is_thinned_evenly_and_said(labelled):
    from jaxpose.training.runner import bounded_test_split
    from jaxpose.training.splits import Splits

    splits = Splits(train=labelled, test=labelled, group_label="action", notes=("loaded",))
    assert bounded_test_split(splits, 0) is splits and bounded_test_split(splits, len(labelled)) is splits
    cap = len(labelled) // 3 - 1  # one in 4 samples kept
    thinned = bounded_test_split(splits, cap)
    kept = np.arange(0, len(labelled), 4)
    assert len(thinned.test) == len(kept) <= cap
    np.testing.assert_array_equal(thinned.test.samples.keypoints2d, labelled.samples.keypoints2d[kept])
    assert thinned.train is labelled and thinned.notes[0] == "loaded"
    assert f"evaluates one in 4 of them ({len(kept):,}" in thinned.notes[1]
