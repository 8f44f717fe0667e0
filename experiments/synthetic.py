"""The main job on the embedded default: procedural multi-view data, self-supervised training,
checkpoints, evaluation and report, in about 10 minutes on 2 CPU cores.

    python -m experiments.synthetic                      # self-supervised (the paper's four losses)
    python -m experiments.synthetic --supervision full   # the same network on 3D ground truth
    python -m experiments.synthetic --help
"""

from __future__ import annotations

import dataclasses
import pathlib

import tyro

from experiments.config import ExperimentConfig, RunConfig, TrainConfig
from experiments.runner import Splits, run
from jaxpose.config import ModelConfig, OptimizerConfig
from jaxpose.data.synthetic import SyntheticConfig, generate


@dataclasses.dataclass(frozen=True)
class SyntheticData:
    """The procedural data set (subjects, motions, rig, detector noise); see jaxpose.data.synthetic."""

    generator: SyntheticConfig = SyntheticConfig()


def load_splits(data: SyntheticData) -> Splits:
    dataset = generate(data.generator)
    return Splits(train=dataset.where(split="train"), test=dataset.where(split="test"), group_label="motion")


DEFAULT = ExperimentConfig(
    data=SyntheticData(),
    model=ModelConfig(),
    optimizer=OptimizerConfig(schedule="cosine", warmup_steps=100),
    train=TrainConfig(batch_size=256, epochs=10, checkpoint_every=500),
    run=RunConfig(run_dir=pathlib.Path("runs/synthetic")),
)


def main(argv: list[str] | None = None) -> dict:
    config = tyro.cli(ExperimentConfig[SyntheticData], default=DEFAULT, args=argv, description=__doc__)
    if config.loss.supervision == "full" and config.run.run_dir == DEFAULT.run.run_dir:
        config = dataclasses.replace(config, run=dataclasses.replace(config.run, run_dir=pathlib.Path("runs/synthetic_supervised")))
    return run(config, load_splits)


if __name__ == "__main__":
    main()
