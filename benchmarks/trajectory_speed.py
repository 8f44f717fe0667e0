"""The trajectory solve of this checkout against an earlier commit's: the same results, and the time ratio.

    python -m benchmarks.trajectory_speed --before 8ef8980

`jaxpose/reconstruction/trajectory.py` of `--before` (read with `git show`, imported beside this checkout's
jaxpose) and this checkout's solve the same recordings: synthetic per-instant evidence (`jaxpose.synthetic`
motions of H36M_17, 5-30 mm per joint with the covariance that says so, a fifth of the cells FUSED and a
twentieth LIFTED, 2% gross outliers of 300 mm, a gap of 6 instants), the prior estimated (the default) and
fixed.  Printed: the largest difference of every output of `solve_trajectory`, then the process CPU time of
each version on `--frames`, the calls alternating so that the machine's load hits both, the medians and
their ratio.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np
import tyro

from jaxpose.reconstruction import trajectory
from jaxpose.reconstruction.fusion import Provenance
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, sample_bone_lengths, sample_motion

MODULE = "jaxpose/reconstruction/trajectory.py"
OUTPUTS = ("points", "sigma", "weight", "limb_lengths", "acceleration_mm_s2", "impact_weight")


@dataclasses.dataclass(frozen=True)
class Args:
    before: str
    """The git revision whose trajectory.py is compared with this checkout's."""
    frames: int = 250
    """Frames of the timed recording (the peers' timing recording's length)."""
    rounds: int = 5
    """Timed calls of each version (alternating); the medians are compared."""


def earlier_module(revision: str):
    """`trajectory.py` of `revision`, imported under another name."""
    root = pathlib.Path(__file__).resolve().parents[1]
    try:
        source = subprocess.run(["git", "show", f"{revision}:{MODULE}"], cwd=root, check=True, capture_output=True, text=True).stdout
    except subprocess.CalledProcessError as error:
        raise SystemExit(f"--before {revision}: git show found no {MODULE} ({error.stderr.strip()})") from None
    path = pathlib.Path(tempfile.mkdtemp()) / "trajectory_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("trajectory_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def recording(seed: int, frames: int, family: str):
    """Per-instant evidence (points, covariance, provenance) of a synthetic motion (module docstring)."""
    rng = np.random.default_rng(seed)
    truth = sample_motion(rng, family, sample_bone_lengths(rng), frames, SyntheticConfig(fps=50)).poses.astype(np.float64)
    sigma = rng.uniform(5.0, 30.0, truth.shape[:2])
    points = truth + rng.normal(0.0, 1.0, truth.shape) * sigma[..., None]
    covariance = (sigma**2)[..., None, None] * np.eye(3)
    provenance = np.full(truth.shape[:2], Provenance.TRIANGULATED)
    provenance[rng.random(provenance.shape) < 0.2] = Provenance.FUSED
    provenance[rng.random(provenance.shape) < 0.05] = Provenance.LIFTED
    outlier = rng.random(truth.shape[:2]) < 0.02
    points[outlier] += rng.normal(0.0, 300.0, (outlier.sum(), 3))
    gap = slice(frames // 3, frames // 3 + 6)
    points[gap], covariance[gap], provenance[gap] = np.nan, np.nan, Provenance.NONE
    return points, covariance, provenance


def main(argv=None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0], prog="python -m benchmarks.trajectory_speed")
    before = earlier_module(args.before)
    cases = [("walking", 250, None), ("waving", 250, None), ("walking", 1000, None), ("walking", 250, 3000.0), ("walking", 3200, None)]
    for seed, (family, frames, fixed) in enumerate(cases):
        evidence = recording(seed, frames, family)
        old, new = (module.solve_trajectory(*evidence, H36M_17.bones, 50.0, module.TrajectoryConfig(acceleration_mm_s2=fixed))
                    for module in (before, trajectory))  # fmt: skip
        differences = []
        for name in OUTPUTS:
            a, b = getattr(old, name).astype(np.float64), getattr(new, name).astype(np.float64)
            same_nan = bool((np.isnan(a) == np.isnan(b)).all())
            differences.append(f"{name} {np.nanmax(np.abs(a - b)) if np.isfinite(a).any() else 0.0:.2g}" + ("" if same_nan else " (NaN differ)"))
        print(f"{family}, {frames} frames, prior {fixed or 'estimated'}: largest |before - now|: {', '.join(differences)}")
    evidence = recording(0, args.frames, "walking")
    times = {"before": [], "now": []}
    for module in (before, trajectory):  # a first call each, not timed
        module.solve_trajectory(*evidence, H36M_17.bones, 50.0)
    for _ in range(args.rounds):
        for name, module in (("before", before), ("now", trajectory)):
            started = time.process_time()
            module.solve_trajectory(*evidence, H36M_17.bones, 50.0)
            times[name].append(time.process_time() - started)
    old, new = np.median(times["before"]), np.median(times["now"])
    print(f"{args.frames} frames x 17 joints, the prior estimated, median CPU s of {args.rounds}: before ({args.before}) {old:.3f},"
          f" now {new:.3f}: {old / new:.2f}x faster ({os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
