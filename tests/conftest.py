import hypothesis
import pytest

from experiments import synthetic as synthetic_job
from jaxpose import inference

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
