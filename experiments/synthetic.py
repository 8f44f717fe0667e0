"""The main job on the embedded default: procedural multi-view data, self-supervised training,
checkpoints, evaluation and report, in about 3 minutes on 2 CPU cores (its budget: 10).

    python -m experiments.synthetic                      # self-supervised (the paper's four losses)
    python -m experiments.synthetic --supervision full   # the same network on 3D ground truth
    python -m experiments.synthetic --preset tiny        # the whole job in seconds: a smoke test
    python -m experiments.synthetic --help
"""

from __future__ import annotations

import dataclasses
import pathlib

from experiments import cli
from jaxpose.training.experiment import ExperimentConfig, RunConfig, TrainConfig
from jaxpose.training.splits import Splits
from jaxpose.training.config import OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.synthetic import SyntheticConfig, generate


@dataclasses.dataclass(frozen=True)
class SyntheticData:
    """The procedural data set (subjects, motions, rig, detector noise); see jaxpose.synthetic."""

    generator: SyntheticConfig = SyntheticConfig()


def load_splits(data: SyntheticData) -> Splits:
    dataset = generate(data.generator)
    return Splits(train=dataset.where(split="train"), test=dataset.where(split="test"), group_label="motion")


# The 10-minute budget on 2 cores: 5 train subjects x 8000 instants = 40k samples x 4 views.  A
# width-512 lifter of two stages trained at ~900 samples/s there (8 epochs, 320k samples, in ~6 min);
# one stage trains about twice as fast, so 15 epochs (600k samples, 2340 steps of 256) take a little
# less time, plus ~1 min for generation, triangulation, compilation and evaluation.  Measured one after
# the other (issue 36, docs/benchmarks.md "The recipe searched again"): 40.4 mm P-MPJPE in 143 s against
# 43.2 in 156 s for 8 epochs of two stages.  The paper's width-1024 network (--model.width 1024)
# manages ~280 samples/s at two stages: under 3 epochs in that time.
DEFAULT = ExperimentConfig(
    data=SyntheticData(),
    model=ModelConfig(width=512, stages=1),
    optimizer=OptimizerConfig(schedule="cosine", warmup_steps=190),
    train=TrainConfig(batch_size=256, epochs=15, checkpoint_every=1000),
    run=RunConfig(run_dir=pathlib.Path("runs/synthetic")),
)


# Preset "tiny": every stage of the job in seconds, to try an installation; the test suite's recipe
# (tests add what they exercise: the epochs, batch and checkpoints of a resume, a temporal window, ...).
# The main job's recipe on a width-64 lifter of ModelConfig's two stages (the tests that read its lifter's
# behaviour were written against it) and 200 instants per subject: 1,000 training samples, one epoch of 3
# steps.  No progress bars, no skeleton plots.
TINY = dataclasses.replace(
    DEFAULT,
    data=SyntheticData(SyntheticConfig(samples_per_subject=200)),
    model=ModelConfig(width=64),
    train=dataclasses.replace(DEFAULT.train, epochs=1),
    run=RunConfig(run_dir=pathlib.Path("runs/synthetic_tiny"), progress=False, plot_samples=0),
)


PRESETS: dict[str, ExperimentConfig] = {"main": DEFAULT, "tiny": TINY}
PRESET_NOTES = {
    "main": "the main job: ~3 min on 2 CPU cores",
    "tiny": "a smoke test, 200 instants per subject (3 steps): seconds",
}


EXPERIMENT = cli.Experiment(name="synthetic", presets=PRESETS, preset_notes=PRESET_NOTES, load_splits=load_splits)


def main(argv: list[str] | None = None) -> dict:
    return cli.main(EXPERIMENT, argv, __doc__)


if __name__ == "__main__":
    main()
