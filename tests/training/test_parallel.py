"""Data parallelism (`jaxpose.training.parallel`): 8 devices train as one does, and a two-process run agrees.

Forced CPU devices and `jax.distributed` must be set up before JAX starts, so the sharded and
multi-process parts run in subprocesses (tests/parallel_worker.py); this process, with its one
device, computes the single-device reference alongside.
"""

import json
import os
import pathlib
import socket
import subprocess
import sys

import jax
import numpy as np
import pytest
from parallel_worker import (
    FIRST_STEPS,
    SAMPLES,
    STEPS,
    TOTAL_STEPS,
    flat,
    process_config,
    reference_problem,
    sharded_run,
)

from jaxpose.training import checkpoint, parallel
from jaxpose.data.dataset import steps_per_epoch
from jaxpose.training.step import init_train_state
import paths

WORKER = paths.TESTS / "parallel_worker.py"
# The tests that start several JAX processes of their own run one after another on one pytest-xdist
# worker (with the fault-tolerance test), so that no two of them share the cores at once.
PROCESSES = "several_processes"
REPO = WORKER.parent.parent


def _start_worker(args: list[str], devices: int, log: pathlib.Path) -> subprocess.Popen:
    # A persistent compilation cache of the test's own, shared by its processes: a resumed run reads the
    # programs its first run compiled (the cached program is the one compiled: results are unaffected).
    cache = {"JAX_COMPILATION_CACHE_DIR": str(log.parent / "jax_cache"), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    env = dict(os.environ, JAX_NUM_CPU_DEVICES=str(devices), JAX_PLATFORMS="cpu", PYTHONPATH=str(REPO), **cache)
    with log.open("w") as output:  # the child keeps its own handle
        return subprocess.Popen([sys.executable, str(WORKER), *args], env=env, cwd=REPO, stdout=output, stderr=subprocess.STDOUT)


def _wait(workers: list[subprocess.Popen], logs: list[pathlib.Path], timeout: float) -> None:
    try:
        for worker in workers:
            worker.wait(timeout=timeout)
    finally:
        for worker in workers:
            if worker.poll() is None:  # timed out, or stuck waiting for a peer that failed
                worker.kill()
                worker.wait()
    for worker, log in zip(workers, logs):
        assert worker.returncode == 0, f"worker exited with {worker.returncode}:\n{log.read_text()[-4000:]}"


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _relative_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-30))


@pytest.mark.processes
@pytest.mark.xdist_group(PROCESSES)
def test_eight_devices_train_as_one(tmp_path):
    out, log = tmp_path / "sharded.npz", tmp_path / "sharded.log"
    worker = _start_worker(["sharded", str(out)], devices=8, log=log)
    # Meanwhile, the single-device references: a plain `jax.jit` of the step (no shardings), and
    # `jit_train_step` on a one-device mesh, which must be the very same computation.
    problem = reference_problem()
    plain_step, state = jax.jit(problem.train_step), problem.initial_state
    for _ in range(STEPS):
        state, _ = plain_step(state, jax.device_put(problem.batch), jax.random.key(1), False)
    plain = jax.device_get(state)
    one_device, one_device_zeros = sharded_run(problem, parallel.data_mesh(1))
    for a, b in zip(jax.tree.leaves(one_device), jax.tree.leaves(plain)):
        np.testing.assert_array_equal(a, b)

    _wait([worker], [log], timeout=240)
    eight = np.load(out)
    reference = {**flat(plain.params, "params"), **flat(plain.batch_stats, "batch_stats")}
    errors = {name: _relative_error(eight[name], value) for name, value in reference.items()}
    # BatchNorm statistics over the global batch (not per device), same dropout masks: the same
    # training up to the order of floating-point sums.
    assert max(errors.values()) < 1e-5, sorted(errors.items(), key=lambda item: -item[1])[:3]
    for name, zeros in flat(one_device_zeros, "zeros").items():
        np.testing.assert_array_equal(eight[name], zeros, err_msg=name)
    assert "does not split evenly over 8 devices" in str(eight["uneven_batch_error"])


@pytest.mark.processes
@pytest.mark.xdist_group(PROCESSES)
def test_two_processes_train_resume_and_agree(tmp_path):
    count, port, run_dir = 2, _free_port(), tmp_path / "run"
    outs = [tmp_path / f"process{i}.npz" for i in range(count)]
    logs = [tmp_path / f"process{i}.log" for i in range(count)]
    workers = [
        _start_worker(["process", str(i), str(count), str(port), str(run_dir), str(outs[i])], devices=2, log=logs[i])
        for i in range(count)
    ]
    _wait(workers, logs, timeout=240)
    results = [np.load(out) for out in outs]
    assert all(int(result["step"]) == TOTAL_STEPS for result in results)
    for name in results[0].files:
        np.testing.assert_array_equal(results[0][name], results[1][name], err_msg=name)
    # One log line per step: written by process 0 only, and the second run resumed at FIRST_STEPS.
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["step"] for line in lines] == list(range(1, TOTAL_STEPS + 1))
    assert sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())[-1] == TOTAL_STEPS
    # The checkpoint is complete on its own: a single-process restore gives the same parameters.
    config = process_config(str(run_dir))
    model = config.model.build(17)
    optimizer = config.optimizer.build(steps_per_epoch(SAMPLES, config.train.batch_size) * config.train.epochs)
    manager = checkpoint.checkpoint_manager(run_dir / "checkpoints", asynchronous=False)
    restored = checkpoint.restore_latest(manager, init_train_state(model, optimizer, jax.random.key(0)))
    assert int(restored.step) == TOTAL_STEPS > FIRST_STEPS
    for name, value in flat(restored.params, "params").items():
        np.testing.assert_array_equal(value, results[0][name], err_msg=name)


def test_a_single_process_does_not_start_the_distributed_runtime(monkeypatch):
    for name in ("SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE"):
        monkeypatch.delenv(name, raising=False)
    assert parallel.initialize() is False
    assert parallel.initialize(num_processes=1) is False


def test_the_data_axis_must_fit_the_devices():
    assert parallel.data_mesh().shape == {"data": jax.device_count()}
    for bad in (0, -2, jax.device_count() + 1):
        with pytest.raises(ValueError, match="data parallelism"):
            parallel.data_mesh(bad)
