import contextlib
import dataclasses
import io
import logging
import os
import pathlib

import hypothesis
import pytest

from experiments import rig as rig_job
from experiments import synthetic as synthetic_job
from jaxpose import compilation_cache, logs
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project

# Hermetic: the command lines run in-process (and the processes the tests start) write no
from jaxpose.serving import inference
# compilation cache to the user's home; a test that wants one names its own folder.
os.environ[compilation_cache.ENVIRONMENT] = compilation_cache.OFF

# Property tests jit per example shape; keep them deterministic and within the CI budget.
hypothesis.settings.register_profile("jaxpose", max_examples=25, deadline=None, derandomize=True)
hypothesis.settings.load_profile("jaxpose")


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    """The synthetic job's tiny preset, shared by the inference and export tests: (run directory, its test split)."""
    run_dir = tmp_path_factory.mktemp("run") / "synthetic"
    synthetic_job.main(["--preset", "tiny", "--run.run-dir", str(run_dir)])
    return run_dir, synthetic_job.load_splits(synthetic_job.TINY.data).test


@pytest.fixture(scope="session")
def lifter(trained_run):
    return inference.load(trained_run[0])


@dataclasses.dataclass(frozen=True)
class RigRun:
    project: pathlib.Path
    gap: range
    """Frames no camera has in the project's first recording: longer than reconstruct's --max-gap."""
    run_dir: pathlib.Path
    log: str
    """What the run logged."""


@pytest.fixture(scope="session")
def rig_run(tmp_path_factory) -> RigRun:
    """An example rig project of 2 recordings of 160 frames and a lifter of a few steps trained on it, enough
    to lift (the fusion judges a lift by the triangulated body), stopped by --train.max-steps before its
    epochs end; shared by the reconstruction and the hostile-input tests."""
    project = write_rig_project(tmp_path_factory.mktemp("rig") / "project", ExampleProjectConfig(recordings=2, frames_per_recording=160, desync_camera=-1))
    gap = range(60, 90)
    first = sorted(p for p in project.iterdir() if p.is_dir() and not p.name.startswith("."))[0]
    for frame in gap:
        for path in first.glob(f"*_json/*_{frame:012d}_keypoints.json"):
            path.unlink()
    run_dir = tmp_path_factory.mktemp("rig_run") / "run"
    log = io.StringIO()
    with contextlib.redirect_stderr(log):
        rig_job.main([
            "--data.root", str(project), "--run.run-dir", str(run_dir), "--model.width", "64", "--train.batch-size", "64",
            "--train.epochs", "4", "--train.max-steps", "10", "--train.eval-every", "10", "--train.eval-samples", "20",
            "--run.no-progress", "--run.plot-samples", "0", "--run.no-tensorboard",
        ])  # fmt: skip
    return RigRun(project, gap, run_dir, log.getvalue())


@pytest.fixture(autouse=True)
def _loggers_as_pytest_sees_them():
    """A command run in-process gives jaxpose's loggers their own terminal handler and stops them
    propagating (jaxpose.logs.show_logs); undo that after each test so the next one's caplog sees them."""
    yield
    for name in logs.LOGGERS:
        logger = logging.getLogger(name)
        logger.propagate = True
        logger.handlers = [handler for handler in logger.handlers if handler.get_name() != logs.HANDLER_NAME]
