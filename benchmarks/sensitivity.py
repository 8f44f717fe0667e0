"""How much one wild keypoint changes the rest of a lifted pose, and what wild joints cost on real data.

    python benchmarks/sensitivity.py --run runs/h36m_dev --data-dir /data/h36m_s1 [--run runs/synthetic ...]

For each trained run (any skeleton whose joint names are among Human3.6M's 17), on real Human3.6M poses:
the development split's test trials (S1, second trial of every action, every 5th frame), the motion
capture projected into one camera each (undistorted pixels, image 1000 x 1000 px):

1. Sensitivity.  For every pose and every joint but the root, that one joint is moved and the pose is
   lifted again with `Lifter3D.predict`; the change is the 3D distance (mm) of each OTHER non-root
   joint between the two predictions, and the table gives its median and 95th percentile over all
   (pose, moved joint, other joint).  Displacements: 0, 25, 50, 100, 200, 400 px in a random direction
   that keeps the joint inside the image (directions that leave it are redrawn; a joint with none is
   skipped); "corner+500": 500 px diagonally beyond a random image corner (the case of the issue);
   "outside": a random point 1 to 1000 px beyond the missing-keypoint margin of a random border.
   Each run is measured three times: as `predict` lifted before the missing-keypoint policy (every
   keypoint as given), with it (`outside_margin`: a keypoint beyond the margin is missing), and with it
   and the rejection of the joint that fits the rest of its pose worst (`reject_inconsistent`, --reject).
   With --flip, every lift is made with test-time flip (`predict(..., flip=True)`).
2. Wild joints on real detections.  The run's own development-split test set with Stacked Hourglass
   detections (16-joint runs only): P-MPJPE over the view-poses that have a joint more than 100 px from
   the projected ground truth, and over those that have none; lifted as given, with the rejection, and
   with exactly the wild joints lifted as missing (what a perfect rejection would give).

Writes a JSON of every number (--out) and prints markdown tables.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys
import time
from collections.abc import Sequence
from typing import Annotated

import numpy as np
import tyro

ROOT_DIR = pathlib.Path(__file__).resolve().parents[1]
if str(ROOT_DIR) not in sys.path:
    sys.path.insert(0, str(ROOT_DIR))

from jaxpose.serving import inference
from jaxpose.training.evaluation import ground_truth_in_views  # noqa: E402
from jaxpose.metrics import p_mpjpe  # noqa: E402

IMAGE_SIZE = (1000.0, 1000.0)
DISPLACEMENTS_PX = (0, 25, 50, 100, 200, 400)
WILD_PX = 100.0


def dev_split(data_dir: pathlib.Path, detections: str):
    """The development split's test set (S1, second trials, every 5th frame) with `detections`."""
    from experiments.h36m import DEV, load_splits
    import dataclasses

    data = dataclasses.replace(DEV.data, data_dir=data_dir, detections=detections)
    return load_splits(data).test


def joint_indices(names_from: tuple[str, ...], names_to: tuple[str, ...]) -> np.ndarray:
    missing = [name for name in names_to if name not in names_from]
    if missing:
        raise SystemExit(f"the lifter's joints {missing} are not Human3.6M joints; this benchmark needs them")
    return np.array([names_from.index(name) for name in names_to])


def sample_poses(test, names: tuple[str, ...], count: int, rng: np.random.Generator):
    """`count` poses, each from one random view: (keypoints f32[M, J, 2] undistorted px, K f32[M, 3, 3])."""
    undistorted = test.undistorted()
    rows = rng.choice(len(test), size=min(count, len(test)), replace=False)
    views = rng.integers(0, test.num_views, size=len(rows))
    index = joint_indices(test.skeleton.joint_names, names)
    keypoints = undistorted.samples.keypoints2d[rows, views][:, index]
    K = np.asarray(test.rigs.K)[test.samples.rig_index[rows], views]
    inside = ((keypoints >= 0) & (keypoints <= np.array(IMAGE_SIZE))).all((1, 2))
    return keypoints[inside].astype(np.float32), K[inside].astype(np.float32)


def displaced(point: np.ndarray, condition, margin: float, rng: np.random.Generator) -> np.ndarray | None:
    """Where one joint goes under `condition` (pixels, or "corner+500" / "outside"); None: no such place."""
    width, height = IMAGE_SIZE
    if condition == "corner+500":
        corner = np.array([rng.integers(0, 2) * width, rng.integers(0, 2) * height])
        outward = np.where(corner > 0, 1.0, -1.0)
        return corner + outward * 500.0 / np.sqrt(2.0)
    if condition == "outside":
        side = rng.integers(0, 4)
        beyond = margin + rng.uniform(1.0, 1000.0)
        along = rng.uniform(-margin, max(width, height) + margin)
        return np.array([(-beyond, along), (width + beyond, along), (along, -beyond), (along, height + beyond)][side])
    if condition == 0:
        return point
    for _ in range(32):
        angle = rng.uniform(0, 2 * np.pi)
        moved = point + condition * np.array([np.cos(angle), np.sin(angle)])
        if (moved >= 0).all() and moved[0] <= width and moved[1] <= height:
            return moved
    return None


PASSES = ("as_given", "policy", "rejecting")


def sensitivity(lifter, keypoints, K, conditions, margin_fraction, lifting: str, reject: float, rng, flip: bool = False) -> dict:
    """{condition: {"median_mm", "p95_mm", "cases"}} for one of `PASSES`, see the module docstring."""
    M, J, _ = keypoints.shape
    margin = margin_fraction * max(IMAGE_SIZE)
    options = dict(image_size=IMAGE_SIZE, outside_margin=None if lifting == "as_given" else margin_fraction, flip=flip)
    if lifting == "rejecting":
        options["reject_inconsistent"] = reject
    base = lifter.predict(keypoints, K, **options)
    results = {}
    for condition in conditions:
        moved, rows, joints = [], [], []
        for i in range(M):
            for j in range(1, J):
                place = displaced(keypoints[i, j], condition, margin, rng)
                if place is None:
                    continue
                pose = keypoints[i].copy()
                pose[j] = place
                moved.append(pose)
                rows.append(i)
                joints.append(j)
        rows, joints = np.array(rows), np.array(joints)
        pred = lifter.predict(np.stack(moved), K[rows], **options)
        change = np.linalg.norm(pred - base[rows], axis=-1)  # [cases, J]
        others = (np.arange(J)[None] != joints[:, None]) & (np.arange(J)[None] != 0)
        values = change[others]
        results[str(condition)] = {
            "median_mm": float(np.median(values)),
            "p95_mm": float(np.percentile(values, 95)),
            "cases": int(len(rows)),
        }
    return results


def wild_joint_errors(lifter, data_dir: pathlib.Path, reject: float, flip: bool = False) -> dict | None:
    """P-MPJPE (mm) of the lifter on the dev split's SH test set, over the view-poses with / without a
    joint more than WILD_PX from the projected ground truth: lifted as given, with `predict`'s
    reject_inconsistent=`reject` (and the share of view-poses it rejects a joint of), and, as the bound
    of any rejection, with exactly the wild joints lifted as missing (an oracle)."""
    sh = dev_split(data_dir, "sh")
    if sh.skeleton.joint_names != lifter.joint_names:
        return None
    gt = dev_split(data_dir, "gt")
    index = joint_indices(gt.skeleton.joint_names, sh.skeleton.joint_names)
    projected = gt.samples.keypoints2d[:, :, index]
    if projected.shape != sh.samples.keypoints2d.shape:
        raise SystemExit(f"SH {sh.samples.keypoints2d.shape} and ground-truth 2D {projected.shape} test sets differ")
    N, C, J, _ = sh.samples.keypoints2d.shape
    offset = np.linalg.norm(sh.samples.keypoints2d - projected, axis=-1).reshape(N * C, J)
    wild_joint = (offset > WILD_PX) & (np.arange(J) != 0)  # the root is never lifted as missing
    wild = (offset > WILD_PX).any(-1)
    keypoints = sh.undistorted().samples.keypoints2d.reshape(N * C, J, 2)
    K = np.asarray(sh.rigs.K)[sh.samples.rig_index].reshape(N * C, 3, 3)
    confidence = sh.samples.confidence.reshape(N * C, J)
    target, valid = ground_truth_in_views(sh)
    target, valid = target.reshape(N * C, J, 3), valid.reshape(N * C)
    rejected = lifter.inconsistent_joints(lifter.prepare(keypoints, K, confidence), threshold=reject)
    lifts = {
        "as_given": confidence,
        "rejecting": np.where(rejected, 0.0, confidence),
        "wild_joints_missing": np.where(wild_joint, 0.0, confidence),
    }
    result = {"share_wild": float((wild & valid).sum() / valid.sum()), "reject": reject}
    kept = offset <= WILD_PX
    for lifting, scores in lifts.items():
        pred = lifter.predict(keypoints, K, scores.astype(np.float32), flip=flip)
        errors = np.asarray(p_mpjpe(pred, target))
        entry = result[lifting] = {}
        for name, mask in (("wild", wild & valid), ("clean", ~wild & valid)):
            entry[name] = {"p_mpjpe_mm": float(errors[mask].mean()), "view_poses": int(mask.sum())}
        # On the poses with a wild joint, the error of the OTHER joints (aligned on them alone): what the
        # wild joint did to the rest of the pose.
        others = [float(p_mpjpe(pred[i][kept[i]], target[i][kept[i]])) for i in np.flatnonzero(wild & valid)]
        entry["wild"]["p_mpjpe_other_joints_mm"] = float(np.mean(others))
    for name, mask in (("wild", wild & valid), ("clean", ~wild & valid)):
        result["rejecting"][name]["rejected_share"] = float(rejected.any(-1)[mask].mean())
    result["rejecting"]["wild"]["wild_joint_rejected_share"] = float((rejected & wild_joint).any(-1)[wild & valid].mean())
    return result


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    run: Annotated[tuple[pathlib.Path, ...], tyro.conf.UseAppendAction, tyro.conf.arg(metavar="RUN")]
    """Run directory of a lifter measured (at least one: --run A --run B ...)."""
    data_dir: Annotated[pathlib.Path, tyro.conf.arg(metavar="DIR")]
    """The h36m.zip tree holding S1 and cameras.h5."""
    poses: int = 200
    """Test poses (one view each)."""
    seed: int = 0
    """Seed of the poses drawn and of the displacements."""
    margin: float = inference.DEFAULT_OUTSIDE_MARGIN
    """--outside-margin of predict: a keypoint beyond it is missing (the missing-keypoint policy)."""
    reject: float = inference.DEFAULT_INCONSISTENT_RESIDUAL
    """--reject-inconsistent of predict: the residual above which the worst-fitting joint is rejected."""
    flip: bool = False
    """Lift with test-time flip (predict's --flip) in every pass."""
    out: pathlib.Path = pathlib.Path("runs/benchmarks/sensitivity.json")
    """The JSON of every number."""


def main(argv: Sequence[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python benchmarks/sensitivity.py")
    if not args.run:
        raise SystemExit("python benchmarks/sensitivity.py: error: --run RUN is required (repeatable)")
    gt = dev_split(args.data_dir, "gt")
    conditions = (*DISPLACEMENTS_PX, "corner+500", "outside")
    report = {"image_size": IMAGE_SIZE, "margin": args.margin, "flip": args.flip, "runs": {}}
    for run in args.run:
        start = time.perf_counter()
        lifter = inference.load(run)
        if lifter.model_config.temporal_window > 1:  # Lifter3D.predict would read the poses as one sequence
            raise SystemExit(f"{run}: a temporal lifter ({lifter.model_config.temporal_window} frames); this benchmark moves joints of single poses")
        keypoints, K = sample_poses(gt, lifter.joint_names, args.poses, np.random.default_rng(args.seed))
        entry = {"normalization": lifter.model_config.input_normalization, "poses": len(keypoints)}
        for lifting in PASSES:
            rng = np.random.default_rng(args.seed + 1)  # the same displacements for all
            entry[lifting] = sensitivity(lifter, keypoints, K, conditions, args.margin, lifting, args.reject, rng, args.flip)
        entry["wild"] = wild_joint_errors(lifter, args.data_dir, args.reject, args.flip)
        entry["seconds"] = time.perf_counter() - start
        report["runs"][str(run)] = entry
        print(f"\n### {run} ({entry['normalization']}, {entry['poses']} poses{', test-time flip' if args.flip else ''})\n")
        print(
            "| one joint moved | as given: median / p95 (mm) | missing-keypoint policy: median / p95 (mm) |"
            f" policy + rejection (residual > {args.reject:g}): median / p95 (mm) |"
        )
        print("|---|---|---|---|")
        for condition in conditions:
            cells = [entry[lifting][str(condition)] for lifting in PASSES]
            label = f"{condition} px" if isinstance(condition, int) else condition
            print(f"| {label} | " + " | ".join(f"{c['median_mm']:.1f} / {c['p95_mm']:.1f}" for c in cells) + " |")
        w = entry["wild"]
        if w is not None:
            print(
                f"\nSH test view-poses with a joint > {WILD_PX:.0f} px off: {w['as_given']['wild']['view_poses']}"
                f" ({100 * w['share_wild']:.1f}%); without: {w['as_given']['clean']['view_poses']}\n"
            )
            print("| lifted | P-MPJPE with (mm) | their other joints alone (mm) | P-MPJPE without (mm) | poses with a joint rejected: with / without |")
            print("|---|---|---|---|---|")
            for lifting, label in (
                ("as_given", "as given"),
                ("rejecting", f"rejecting (residual > {args.reject:g})"),
                ("wild_joints_missing", "the wild joints as missing (oracle)"),
            ):
                a, b = w[lifting]["wild"], w[lifting]["clean"]
                share = f"{100 * a['rejected_share']:.1f}% / {100 * b['rejected_share']:.2f}%" if "rejected_share" in a else "-"
                print(f"| {label} | {a['p_mpjpe_mm']:.1f} | {a['p_mpjpe_other_joints_mm']:.1f} | {b['p_mpjpe_mm']:.1f} | {share} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main()
