"""The main job survives being killed at any point, mid-checkpoint included, and a corrupt checkpoint.

Black-box: `python -m experiments.synthetic` on a tiny config runs as a subprocess, is SIGKILLed at
several points (once after checkpoints were committed, once while Orbax is writing one, detected by
its in-progress directory), has its newest checkpoint corrupted (mid-run, and the final one of the
finished run), and is restarted on the same run directory each time.  It must end with the state
(every parameter, BatchNorm statistic and Adam moment), the metrics of every logged step and the
report of an uninterrupted run, bit for bit (CPU).
The uninterrupted run is a separate process with the same seed, so this also shows that a seed
fixes the whole run.
"""

from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest
import paths

pytestmark = [pytest.mark.trains, pytest.mark.processes]

REPO = paths.REPO
# The tiny preset on 1,500 training samples, batch 64: 23 steps per epoch, 46 steps, a checkpoint every 4 steps.
TINY = [
    "--preset", "tiny", "--train.epochs", "2", "--train.batch-size", "64", "--train.checkpoint-every", "4",
    "--train.log-every", "1", "--data.generator.samples-per-subject", "300",
    # The robust input path (issue 26): median normalisation and the detector-failure augmentation,
    # whose draws come from the step's key, so a resumed run must draw what an uninterrupted one does.
    "--model.input-normalization", "intrinsics_median", "--train.augment.drop", "0.1",
    "--train.augment.displace", "0.1", "--train.augment.swap", "0.05",
]  # fmt: skip
TOTAL_STEPS = 46
TIMEOUT_S = 240
IN_PROGRESS = "orbax-checkpoint-tmp"


def _env(cache: pathlib.Path) -> dict[str, str]:
    # A shared persistent compilation cache: restarts skip most of the compilation.  The cached
    # executable is the one compiled, so results are unaffected.
    return dict(
        os.environ,
        JAX_PLATFORMS="cpu",
        JAX_COMPILATION_CACHE_DIR=str(cache),
        JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
        JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0",
    )


class Job:
    """Starts the tiny synthetic job on one run directory; each attempt logs to its own file."""

    def __init__(self, run_dir: pathlib.Path, cache: pathlib.Path):
        self.run_dir, self.cache, self.attempts = run_dir, cache, 0

    def start(self) -> subprocess.Popen:
        self.attempts += 1
        log = open(self.run_dir.parent / f"{self.run_dir.name}.attempt{self.attempts}.log", "w")
        command = [sys.executable, "-m", "experiments.synthetic", "--run.run-dir", str(self.run_dir), *TINY]
        return subprocess.Popen(command, cwd=REPO, env=_env(self.cache), stdout=log, stderr=subprocess.STDOUT)

    def log(self) -> str:
        return (self.run_dir.parent / f"{self.run_dir.name}.attempt{self.attempts}.log").read_text()

    @property
    def checkpoints(self) -> pathlib.Path:
        return self.run_dir / "checkpoints"

    def committed(self) -> list[int]:
        if not self.checkpoints.is_dir():
            return []
        return sorted(int(p.name) for p in self.checkpoints.iterdir() if p.name.isdigit())

    def in_progress(self) -> list[pathlib.Path]:
        if not self.checkpoints.is_dir():
            return []
        return [p for p in self.checkpoints.iterdir() if IN_PROGRESS in p.name]


def _wait_for(process: subprocess.Popen, condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        if process.poll() is not None:
            pytest.fail(f"the job exited (code {process.returncode}) before {what}")
        if time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.002)


def _sigkill(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGKILL)
    assert process.wait(30) == -signal.SIGKILL


def _finish(process: subprocess.Popen, job: Job) -> None:
    assert process.wait(TIMEOUT_S) == 0, job.log()[-3000:]


def _final_state(job: Job) -> dict:
    manager = ocp.CheckpointManager(job.checkpoints.absolute())
    step = manager.latest_step()
    assert step == TOTAL_STEPS
    state = manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore()))["state"]
    manager.close()
    return state


def _metrics_by_step(job: Job) -> dict[int, dict]:
    """Each logged step's values (wall-clock throughput aside).  A step logged again after a restart
    (it was past the last checkpoint when the job died) must repeat its values exactly."""
    by_step: dict[int, dict] = {}
    for line in (job.run_dir / "metrics.jsonl").read_text().splitlines():
        record = json.loads(line)
        record.pop("samples_per_s")
        step = record["step"]
        assert by_step.setdefault(step, record) == record, f"step {step} replayed differently after a restart"
    return by_step


def _corrupt_newest(job: Job) -> tuple[int, int]:
    return _corrupt_newest_in(job.checkpoints)


def _corrupt_newest_in(checkpoints: pathlib.Path) -> tuple[int, int]:
    """Truncate the largest file of the newest committed step's train state (the item a resume reads);
    returns (corrupted, previous) steps."""
    steps = sorted(int(p.name) for p in checkpoints.iterdir() if p.name.isdigit())
    assert len(steps) >= 2, steps
    files = [p for p in (checkpoints / str(steps[-1]) / "state").rglob("*") if p.is_file()]
    largest = max(files, key=lambda p: p.stat().st_size)
    with largest.open("r+b") as handle:
        handle.truncate(largest.stat().st_size // 2)
    return steps[-1], steps[-2]


@pytest.mark.xdist_group("several_processes")  # one at a time with tests/training/test_parallel.py's
def test_killed_and_corrupted_runs_end_bit_identical_to_an_uninterrupted_one(tmp_path):
    cache = tmp_path / "jax_cache"
    reference = Job(tmp_path / "reference", cache)
    reference_process = reference.start()  # runs beside the interrupted job
    job = Job(tmp_path / "interrupted", cache)

    # 1. Killed while training, after two checkpoints were committed.
    process = job.start()
    _wait_for(process, lambda: len(job.committed()) >= 2, "two committed checkpoints")
    _sigkill(process)

    # 2. Killed while Orbax writes a checkpoint: its in-progress directory is left behind.
    killed_mid_save = False
    while not killed_mid_save:
        assert job.attempts < 6, "never caught a checkpoint in progress"
        process = job.start()
        newest = max(job.committed(), default=0)
        _wait_for(process, lambda: any(int(p.name.split(".")[0]) > newest for p in job.in_progress()), "a save")
        _sigkill(process)
        killed_mid_save = bool(job.in_progress())  # else the save completed between poll and kill

    # 3. The newest committed checkpoint corrupted: reported, the previous one used, run completed.
    corrupted, previous = _corrupt_newest(job)
    process = job.start()
    _finish(process, job)
    log = job.log()
    assert f"checkpoint step {corrupted}" in log and "unreadable" in log and "falling back" in log, log[-3000:]
    assert f"resumed from step {previous} of {TOTAL_STEPS}" in log, log[-3000:]  # jaxpose's INFO lines are shown
    assert not job.in_progress(), "the interrupted save's directory was not cleaned up"
    assert corrupted <= previous + 4 and previous in _metrics_by_step(job)

    # 4. The finished run's final checkpoint corrupted, the job run again: the last steps are trained
    # again and the final checkpoint rewritten (not left corrupt, to be skipped by every later load).
    corrupted, previous = _corrupt_newest(job)
    assert corrupted == TOTAL_STEPS
    process = job.start()
    _finish(process, job)
    assert f"checkpoint step {TOTAL_STEPS}" in job.log() and "falling back" in job.log()

    _finish(reference_process, reference)
    expected, actual = _final_state(reference), _final_state(job)
    assert jax.tree.structure(actual) == jax.tree.structure(expected)
    for path, want in jax.tree_util.tree_leaves_with_path(expected):
        got = dict(jax.tree_util.tree_leaves_with_path(actual))[path]
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want), err_msg=jax.tree_util.keystr(path))

    expected_metrics, actual_metrics = _metrics_by_step(reference), _metrics_by_step(job)
    assert sorted(expected_metrics) == list(range(1, TOTAL_STEPS + 1))
    assert actual_metrics == expected_metrics

    report, expected_report = (json.loads((j.run_dir / "report.json").read_text()) for j in (job, reference))
    assert report["results"] == expected_report["results"]


def test_restore_latest_reports_an_unreadable_step_and_can_discard_it(tmp_path):
    """In-process and fast: the fallback itself, and that a resuming run can save the step again."""
    from jaxpose.training import checkpoint
    from jaxpose.model import ModelConfig
    from jaxpose.skeleton import H36M_17
    from jaxpose.training.step import TrainState

    def state(step: int) -> TrainState:
        params = {"w": jnp.full((64, 64), float(step))}
        return TrainState(step=jnp.asarray(step), params=params, batch_stats={}, opt_state=())

    lifter = checkpoint.LifterRecord(H36M_17, ModelConfig())
    manager = checkpoint.checkpoint_manager(tmp_path, asynchronous=False)
    for step in (1, 2):
        checkpoint.save(manager, state(step), lifter)
    corrupted, _ = _corrupt_newest_in(tmp_path)
    assert corrupted == 2
    with pytest.warns(UserWarning, match="checkpoint step 2 .* unreadable"):
        kept = checkpoint.restore_latest(manager, state(0))
    assert int(kept.step) == 1 and manager.all_steps() == [1, 2]  # by default nothing is deleted
    with pytest.warns(UserWarning, match="checkpoint step 2"):
        restored = checkpoint.restore_latest(manager, state(0), discard_unreadable=True)
    np.testing.assert_array_equal(restored.params["w"], 1.0)
    assert manager.all_steps() == [1]
    checkpoint.save(manager, state(2), lifter)
    assert int(checkpoint.restore_latest(manager, state(0)).step) == 2
    with pytest.raises(checkpoint.CheckpointError, match="no readable checkpoint"), pytest.warns(UserWarning):
        checkpoint.restore_latest(manager, state(0).replace(params={"w": jnp.zeros((3,))}), discard_unreadable=True)
    assert manager.all_steps() == [1, 2]  # a template that fits no step deletes nothing
    manager.close()
