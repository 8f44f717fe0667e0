import logging
import os

import hypothesis
import pytest

from experiments import synthetic as synthetic_job
from jaxpose import compilation_cache, logs

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


@pytest.fixture(autouse=True)
def _loggers_as_pytest_sees_them():
    """A command run in-process gives jaxpose's loggers their own terminal handler and stops them
    propagating (jaxpose.logs.show_logs); undo that after each test so the next one's caplog sees them."""
    yield
    for name in logs.LOGGERS:
        logger = logging.getLogger(name)
        logger.propagate = True
        logger.handlers = [handler for handler in logger.handlers if handler.get_name() != logs.HANDLER_NAME]
