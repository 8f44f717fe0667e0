import contextlib
import dataclasses
import io
import logging
import os
import pathlib

import hypothesis
import jax
import pytest

from experiments import rig as rig_job
from experiments import synthetic as synthetic_job
from jaxpose import compilation_cache, logs
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project

from jaxpose.serving import inference

# Hermetic: the command lines run in-process (and the processes the tests start) write no
# compilation cache to the user's home (this run's own: compilation_cache_of_the_run).
os.environ[compilation_cache.ENVIRONMENT] = compilation_cache.OFF

# Property tests jit per example shape; keep them deterministic and within the CI budget.
hypothesis.settings.register_profile("jaxpose", max_examples=25, deadline=None, derandomize=True)
hypothesis.settings.load_profile("jaxpose")


# The shared run: the tiny preset for 50 epochs (150 steps, past the start where its lifter is still worse than
# the mean pose: tests/experiments/test_training_works.py; the output triangulation term is on in the last 15),
# every step logged, evaluated every 4 steps and at the end, with the figures of 4 samples.
TRAINED_RUN_ARGS = ["--preset", "tiny", "--train.epochs", "50", "--train.log-every", "1", "--train.eval-every", "4", "--run.plot-samples", "4"]


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    """The synthetic job's tiny preset (`TRAINED_RUN_ARGS`), shared by the inference and export tests and by
    those of the run directory it writes (tests/experiments/test_end_to_end.py): (run directory, its test split)."""
    run_dir = tmp_path_factory.mktemp("run") / "synthetic"
    synthetic_job.main([*TRAINED_RUN_ARGS, "--run.run-dir", str(run_dir)])
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


@pytest.fixture(scope="session", autouse=True)
def compilation_cache_of_the_run(tmp_path_factory):
    """JAX's persistent compilation cache on in every test process, in one folder of this pytest run (the
    xdist workers' shared base folder): the many tests that compile the same train step, evaluation and
    loading programs read them back instead of compiling them again, as the command lines do with their
    cache.  A cached program is the one compiled, so no result changes.  The command lines run in-process
    keep the cache JAX was given (jaxpose.compilation_cache); the processes the tests start have none."""
    from jax.experimental.compilation_cache import compilation_cache as jax_cache

    base = tmp_path_factory.getbasetemp()
    folder = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "xla"
    folder.mkdir(exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", compilation_cache.MIN_COMPILE_TIME_S)
    jax_cache.reset_cache()  # JAX decides at its first compilation whether the cache is on: ask it again
    yield folder


# The session fixtures that train: the modules using any of them are one xdist group, so each trains once
# (a module may use several: the hostile-input tests use both).
SHARED_RUNS, SHARED_RUNS_GROUP = ("trained_run", "rig_run"), "shared_runs"


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups into the node ids
def pytest_collection_modifyitems(items):
    """The suite runs on every core (pytest-xdist, `--dist loadgroup` in pyproject.toml): a test goes to
    whichever worker is free, except that the tests sharing a fixture made once per module or session
    stay on one worker, so that it is still made once.  The modules that use a shared run (`SHARED_RUNS`,
    directly or through another fixture) are one group; every other module that uses a module-scoped
    fixture is a group of its own; a test marked `xdist_group` keeps its group."""
    modules: dict[str, list[pytest.Item]] = {}
    for item in items:
        modules.setdefault(item.nodeid.split("::")[0], []).append(item)
    for module, members in modules.items():
        if any(run in item.fixturenames for item in members for run in SHARED_RUNS):
            group = SHARED_RUNS_GROUP
        elif any(_uses_a_module_fixture(item) for item in members):
            group = module
        else:
            continue
        for item in members:
            if item.get_closest_marker("xdist_group") is None:
                item.add_marker(pytest.mark.xdist_group(group))


def _uses_a_module_fixture(item: pytest.Item) -> bool:
    definitions = getattr(item, "_fixtureinfo", None)
    if definitions is None:
        return False
    return any(defs and defs[-1].scope == "module" for defs in definitions.name2fixturedefs.values())


@pytest.fixture(autouse=True)
def _loggers_as_pytest_sees_them():
    """A command run in-process gives jaxpose's loggers their own terminal handler and stops them
    propagating (jaxpose.logs.show_logs); undo that after each test so the next one's caplog sees them."""
    yield
    for name in logs.LOGGERS:
        logger = logging.getLogger(name)
        logger.propagate = True
        logger.handlers = [handler for handler in logger.handlers if handler.get_name() != logs.HANDLER_NAME]
