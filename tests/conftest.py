import json

import hypothesis
import pytest

from experiments import synthetic as synthetic_job
from jaxpose import inference
from jaxpose.synthetic import SyntheticConfig

# Property tests jit per example shape; keep them deterministic and within the CI budget.
hypothesis.settings.register_profile("jaxpose", max_examples=25, deadline=None, derandomize=True)
hypothesis.settings.load_profile("jaxpose")


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory):
    """A tiny self-supervised synthetic run, shared by the inference and export tests:
    (run directory, its test split)."""
    run_dir = tmp_path_factory.mktemp("run") / "synthetic"
    synthetic_job.main([
        "--run.run-dir", str(run_dir), "--model.width", "64", "--train.epochs", "1", "--train.max-steps", "30",
        "--data.generator.samples-per-subject", "200", "--run.no-progress", "--run.plot-samples", "0",
    ])  # fmt: skip
    generator = json.loads((run_dir / "config.json").read_text())["data"]["generator"]
    generator = SyntheticConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in generator.items()})
    return run_dir, synthetic_job.load_splits(synthetic_job.SyntheticData(generator)).test


@pytest.fixture(scope="session")
def lifter(trained_run):
    return inference.load(trained_run[0])
