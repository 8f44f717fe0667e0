"""Sessions found from the data (`jaxpose.calibration.sessions.find_sessions`) on simulated projects
whose cameras moved between sessions.

    python -m experiments.sessions_study                 # seeds 0 and 1 (~6 min on 2 cores)
    python -m experiments.sessions_study --h36m-project runs/h36m_s1_sessions   # Human3.6M S1 as two sessions

Per seed: a rig (the synthetic room) and the same rig with every camera moved by 100-500 mm and
turned by 1-3 degrees; the same subject filmed in four recordings of 300 frames (two per rig, four
different motions) through the default detector (3-8 px noise, outliers, swaps, missing joints),
K given.  Printed: the sessions found, the fit matrix (px: the worst camera's median re-projection
error of each recording, column, through each recording's own recovered rig, row; "no rig" where
that recording's calibration failed, "behind" where most points triangulate behind a camera), why
a calibration failed, and each recovered rig against the rig that filmed it after a similarity
alignment.

With --h36m-project (a project `experiments.rig_from_h36m --no-calibration --moved ...` wrote: S1 as two
sessions, the second through a moved rig): the project is loaded through the rig loader (no calibration,
the development protocol: every 5th instant, the first trial of each action training), and printed are
the sessions found, per session and camera the rotation (deg) and centre (mm) error of the recovered rig
after one similarity alignment to the truth (cameras.h5, and `moved_rig.npz` for the moved recordings),
and the triangulation world MPJPE of the held-out recordings after one similarity alignment per session,
beside the triangulation through the true cameras and through one rig recovered from every recording
(--data.no-find-sessions, today's behaviour before sessions).
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np
import tyro

from jaxpose.calibration import CalibrationConfig, RigDetections, compare_rigs
from jaxpose.calibration.sessions import find_sessions
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, make_rig, sample_bone_lengths, sample_motion
from jaxpose.synthetic.sessions import moved_rig, record

PLAN = (("a1", "A", "walking"), ("a2", "A", "reaching"), ("b1", "B", "turning"), ("b2", "B", "gesturing"))


@dataclasses.dataclass(frozen=True)
class Args:
    """Find the sessions of simulated two-rig projects and compare them with the truth."""

    seeds: tuple[int, ...] = (0, 1)
    frames: int = 300
    """Frames per recording."""
    max_frames: int = 150
    """Frames each recording's calibration uses."""
    h36m_project: pathlib.Path | None = None
    """A Human3.6M project of two sessions (`experiments.rig_from_h36m --moved`): measure the loader on it instead."""
    data_dir: pathlib.Path = pathlib.Path("../shared/data/h36m_s1")
    """With --h36m-project: the Human3.6M folder whose cameras.h5 holds the true rig."""
    recovery_frames: int = 600
    """With --h36m-project: --data.recovery-frames, the instants each session's rig is recovered from."""
    one_rig: bool = True
    """With --h36m-project: also load it with one rig for every recording (--data.no-find-sessions)."""


def main(argv=None) -> list:
    args = tyro.cli(Args, args=argv, prog="python -m experiments.sessions_study", description=__doc__.split("\n\n")[0])
    if args.h36m_project is not None:
        from experiments.sessions_h36m import h36m_study

        return h36m_study(args.h36m_project, args.data_dir, args.recovery_frames, args.one_rig)
    config = SyntheticConfig()
    names = ("c0", "c1", "c2", "c3")
    results = []
    for seed in args.seeds:
        rng = np.random.default_rng([seed, 43])
        rigs = {"A": make_rig(rng, config)}
        rigs["B"] = moved_rig(rng, rigs["A"])
        bones = sample_bone_lengths(rng)
        recordings = {}
        for name, rig, motion in PLAN:
            keypoints, confidence = record(rng, rigs[rig], sample_motion(rng, motion, bones, args.frames, config).poses, config)
            recordings[name] = RigDetections(
                keypoints, confidence, names, np.full((4, 2), 1000), H36M_17, K=np.asarray(rigs["A"].K, np.float64), source=name
            )
        grouping = find_sessions(recordings, CalibrationConfig(max_frames=args.max_frames))
        print(f"\nseed {seed}: sessions {[session.recordings for session in grouping.sessions]}, unfitted {list(grouping.unfitted)}")
        print("| rig of \\ recording | " + " | ".join(grouping.recordings) + " |\n|---|" + "---|" * len(grouping.recordings))
        for name, row in zip(grouping.recordings, grouping.fit_px):
            cells = ("no rig" if np.isnan(value) else "behind" if value >= 1e4 else f"{value:.1f}" for value in row)
            print(f"| {name} | " + " | ".join(cells) + " |")
        for name, why in grouping.failures.items():
            print(f"{name}: no rig of its own: {why}")
        for name, rig, _ in PLAN:
            if name not in grouping.calibrations:
                continue
            truth = rigs[rig]
            recovered = grouping.calibrations[name].cameras
            comparison = compare_rigs(recovered.R, recovered.t, np.asarray(truth.R, np.float64), np.asarray(truth.t, np.float64))
            print(
                f"{name}: rotation error max {comparison.rotation_deg.max():.2f} deg, centre error max"
                f" {comparison.centre_mm.max():.1f} mm, {grouping.calibrations[name].seconds:.0f} s"
            )
        results.append(grouping)
    return results


if __name__ == "__main__":
    main()
