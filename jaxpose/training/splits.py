"""What an entry point's data loader hands the runner: the train and test splits and how to report them."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from jaxpose.data.dataset import MultiViewDataset
from jaxpose.training.run_directory import RunDirectory, RunRecord


@dataclasses.dataclass(frozen=True)
class Splits:
    """What an entry point's data loader returns."""

    train: MultiViewDataset
    test: MultiViewDataset
    group_label: str
    """The label that groups test results (e.g. "action", "motion")."""
    detector_specific_joints: tuple[str, ...] = ()
    """Joints that the 2D source defines differently from the 3D ground truth (e.g. Stacked
    Hourglass's MPII "Spine" and "Head" on Human3.6M).  The report adds every metric over the other
    joints (Procrustes-aligned on those joints alone), where the definitions agree."""
    camera_names: tuple[str, ...] = ()
    """The views' names, for the per-camera tables (default: view 0, 1, ...)."""
    notes: tuple[str, ...] = ()
    """Paragraphs for the top of the report: what the loader did to the data (e.g. a rig project's
    calibration, frame offsets and person choices)."""
    artifacts: tuple[Callable[[RunDirectory], None], ...] = ()
    """Files the loader made for the run directory: functions writing each into it (e.g. the rig
    `jaxpose.calibrate` recovered, to `RunDirectory.recovered_cameras`)."""
    record: RunRecord = RunRecord()
    """What the run records of its input for the commands that use it (`run_directory.RunRecord`)."""
    def view_names(self) -> tuple[str, ...]:
        return self.camera_names or tuple(f"view {c}" for c in range(self.test.num_views))

    def agreeing_joints(self) -> np.ndarray | None:
        """Indices of the joints not in `detector_specific_joints`; None when every joint agrees."""
        if not self.detector_specific_joints:
            return None
        names = self.test.skeleton.joint_names
        return np.array([i for i, name in enumerate(names) if name not in self.detector_specific_joints], dtype=int)
