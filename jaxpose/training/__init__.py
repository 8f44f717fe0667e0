"""Training a lifter and judging it: the jitted step (`step`), configs (`config`, `experiment`), checkpoints,
multi-device training (`parallel`), the pseudo-labels, evaluation with and without ground truth
(`evaluation`, `self_consistency`), and the run itself (`runner` over `splits`, `loop`, `report`,
`run_directory`), so that the library trains without the entry points of `experiments/`."""
