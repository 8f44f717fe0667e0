"""Several people on Campus: association across views (`jaxpose.rig.association`), tracks over time
(`jaxpose.rig.tracks`), scored by the field's measure, beside the one-person path (`jaxpose.rig.people.choose`).

    python -m benchmarks.people [--campus ../shared/data/multiperson/campus] [--seeds 0 1 2] [--without-calibration]

Campus (3 cameras, 360x288 px, 25 fps, 2,000 frames, 3D ground truth of up to 3 people) with its given
calibration (pinhole: its ground truth projects onto its 2D annotations without the distortion it lists).
Its 2D are annotations, so a simulated detector corrupts them (`simulate`, parameters in `NOISE`): per-axis
Gaussian noise, missing joints, people missed in a view, left/right swaps and false people (a real pose of
another frame placed anywhere in the image).  Scores, on the frames whose ground truth lists somebody:

- PCP (percentage of correct parts): a limb is correct when the mean of its two end-point errors is at most
  half its length; each ground-truth person is scored against the output person nearest to it at that instant
  (none: every limb wrong); per person and averaged over the three;
- MPJPE (mm) per person, of the same pairs;
- identity switches: a ground-truth person paired (within 500 mm) with another track than at its last pairing;
- false people: output people paired with no ground-truth person (one-to-one, within 500 mm); missed: the reverse;
- instants per second of association and tracks.

--without-calibration: the rig recovered from the people instead (`without_calibration`: the detections matched
across views by their epipolar geometry, `jaxpose.calibration.matching`, then `jaxpose.calibration.calibrate` with
Campus' intrinsics; everyone associated through that rig and the rig recovered again, as the rig loader does), its
error against Campus' calibration (both rigs), and the PCP of the same association and tracks through it
beside the calibrated run's.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from jaxpose.rig import association, people, tracks
from jaxpose.rig.geometry import triangulate_rows

CAMPUS = Path(__file__).resolve().parents[2] / "shared" / "data" / "multiperson" / "campus"
CAMERAS = ("Camera0", "Camera1", "Camera2")
FPS = 25.0
# The Campus/Shelf 14 joints: r ankle, r knee, r hip, l hip, l knee, l ankle, r wrist, r elbow, r shoulder,
# l shoulder, l elbow, l wrist, neck (bottom of the head), top of the head.
FLIP = np.array([5, 4, 3, 2, 1, 0, 11, 10, 9, 8, 7, 6, 12, 13])
LIMBS = np.array([[0, 1], [1, 2], [3, 4], [4, 5], [6, 7], [7, 8], [9, 10], [10, 11], [12, 13]])
"""The nine limbs between joints; the torso (mid-hip to neck) is the tenth, `limb_ends`."""
PAIRING_MM = 500.0
MAX_GAP = 10  # instants a track's joint is interpolated over (0.4 s)
THRESHOLD_PX = 15.0  # association: the images are 360x288, the people 60-120 px tall


@dataclasses.dataclass(frozen=True)
class Noise:
    """The simulated detector on Campus's annotations."""

    sigma_px: tuple[float, ...] = (2.5, 2.0, 1.5, 1.5, 2.0, 2.5, 2.5, 2.0, 1.5, 1.5, 2.0, 2.5, 1.5, 1.5)
    """Per-axis Gaussian noise of each joint: ankles and wrists 2.5 px, knees and elbows 2, the rest 1.5."""
    missing_joint: float = 0.02
    missed_person: float = 0.05
    """Of each person in each view."""
    swap: float = 0.02
    """Of each person in each view: left and right exchanged."""
    false_people: float = 0.2
    """Per view and frame (Poisson mean)."""
    score: float = 0.9


NOISE = Noise()


@dataclasses.dataclass(frozen=True)
class Campus:
    P: np.ndarray  # f32[C, 3, 4] pixels from world mm
    clean: list  # per frame, per view: f32[k, J, 2] annotated people
    truth: list  # per frame: dict id -> f32[J, 3] mm
    image_size: tuple[int, int]


def load_campus(root: Path) -> Campus:
    calibration = json.loads((root / "calibration.json").read_text())["cameras"]
    annotations = json.loads((root / "annotation_2d.json").read_text())
    truth3d = json.loads((root / "annotation_3d.json").read_text())
    width, height = annotations["image_wh"]
    P = []
    for camera in CAMERAS:
        K = np.array(calibration[camera]["K"]) * np.array([[width], [height], [1]])
        Tw = np.array(calibration[camera]["Tw"])  # camera to world, cm
        R = Tw[:3, :3].T
        P.append(K @ np.hstack([R, -R @ Tw[:3, 3:] * 10.0]))
    clean = []
    for frame in range(len(truth3d)):
        views = []
        for camera in CAMERAS:
            entry = annotations["frames"].get(f"{camera}/{frame // 25:04d}.{(frame % 25) * 40:03d}.jpg", {"poses": []})
            views.append(np.array([pose["points_2d"] for pose in entry["poses"]], np.float32).reshape(-1, 14, 2))
        clean.append(views)
    truth = [{pose["id"]: np.array(pose["points_3d"], np.float32) * 10.0 for pose in f["poses"]} for f in truth3d]
    return Campus(np.array(P, np.float32), clean, truth, (width, height))


def simulate(campus: Campus, seed: int, noise: Noise = NOISE) -> tuple[np.ndarray, np.ndarray]:
    """The simulated detector's output: keypoints f32[N, C, K, J, 2], confidence f32[N, C, K, J], each
    view's people in random order."""
    rng = np.random.default_rng(seed)
    sigma = np.array(noise.sigma_px, np.float32)
    pool = [pose for views in campus.clean for poses in views for pose in poses]
    detected = []
    for views in campus.clean:
        frame = []
        for poses in views:
            kept = [p[FLIP] if rng.random() < noise.swap else p for p in poses if rng.random() >= noise.missed_person]
            for _ in range(rng.poisson(noise.false_people)):
                fake = pool[rng.integers(len(pool))]
                centre = rng.uniform((0, 0), campus.image_size)
                kept.append(fake - fake.mean(0) + centre)
            kept = [p + rng.normal(0, 1, p.shape).astype(np.float32) * sigma[:, None] for p in kept]
            frame.append([kept[i] for i in rng.permutation(len(kept))])
        detected.append(frame)
    K = max(1, max(len(poses) for frame in detected for poses in frame))
    N, C, J = len(detected), len(CAMERAS), 14
    keypoints = np.zeros((N, C, K, J, 2), np.float32)
    confidence = np.zeros((N, C, K, J), np.float32)
    for n, frame in enumerate(detected):
        for c, poses in enumerate(frame):
            for k, pose in enumerate(poses):
                keypoints[n, c, k] = pose
                confidence[n, c, k] = np.where(rng.random(J) < noise.missing_joint, 0.0, noise.score)
    return keypoints, confidence


def limb_ends(pose: np.ndarray) -> np.ndarray:
    """f32[..., J, 3] -> f32[..., 10, 2, 3]: the nine `LIMBS` and the torso (mid-hip to neck)."""
    ends = pose[..., LIMBS, :]
    torso = np.stack([(pose[..., 2, :] + pose[..., 3, :]) / 2, pose[..., 12, :]], -2)
    return np.concatenate([ends, torso[..., None, :, :]], -3)


def pcp(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """bool[10]: each limb correct (mean end-point error <= half its true length); a NaN end is wrong."""
    e, t = limb_ends(estimate), limb_ends(truth)
    error = np.linalg.norm(e - t, axis=-1).mean(-1)
    return np.nan_to_num(error, nan=np.inf) <= np.linalg.norm(t[:, 0] - t[:, 1], axis=-1) / 2


def score(campus: Campus, points: np.ndarray, identity: np.ndarray) -> dict:
    """points f32[N, M, J, 3], identity int[N, M] (-1: no output person) -> the scores of the module docstring."""
    ids = sorted({i for frame in campus.truth for i in frame})
    correct = {i: [] for i in ids}
    errors = {i: [] for i in ids}
    last = {}
    switches = false = missed = 0
    for n, frame in enumerate(campus.truth):
        if not frame:
            continue
        out = np.flatnonzero(identity[n] >= 0)
        truth_ids = list(frame)
        distance = np.full((len(truth_ids), len(out)), np.inf)
        for a, i in enumerate(truth_ids):
            for b, m in enumerate(out):
                distance[a, b] = np.nanmean(np.linalg.norm(points[n, m] - frame[i], axis=-1))
            # PCP and MPJPE: the nearest output person, as the field scores Campus
            nearest = out[np.argmin(distance[a])] if len(out) and np.isfinite(distance[a]).any() else None
            if nearest is None:
                correct[i].append(np.zeros(10, bool))
            else:
                correct[i].append(pcp(points[n, nearest], frame[i]))
                errors[i].append(distance[a].min())
        rows, cols = linear_sum_assignment(np.where(np.isfinite(distance), distance, 1e9)) if len(out) else ([], [])
        paired = [(r, c) for r, c in zip(rows, cols) if distance[r, c] <= PAIRING_MM]
        false += len(out) - len(paired)
        missed += len(truth_ids) - len(paired)
        for r, c in paired:
            track = identity[n, out[c]]
            switches += truth_ids[r] in last and last[truth_ids[r]] != track
            last[truth_ids[r]] = track
    per_person = {i: 100 * np.mean(correct[i]) for i in ids}
    return {
        "pcp": per_person,
        "average": float(np.mean(list(per_person.values()))),
        "mpjpe": {i: float(np.mean(errors[i])) for i in ids},
        "switches": int(switches),
        "false": int(false),
        "missed": int(missed),
    }


def several(campus: Campus, keypoints: np.ndarray, confidence: np.ndarray, people_count: int | None) -> tuple:
    start = time.perf_counter()
    found = association.associate(campus.P, keypoints, confidence, THRESHOLD_PX)
    followed = tracks.follow(found.points, found.present, LIMBS, tracks.TrackSettings(fps=FPS, people=people_count))
    points = tracks.track_points(found.points, followed.identity, followed.count, MAX_GAP)
    seconds = time.perf_counter() - start
    return found, followed, points, seconds


def one_person(campus: Campus, keypoints: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Today's single-person path: `people.choose_person`'s detections triangulated, f32[N, 1, J, 3]."""
    choice = people.choose_person(campus.P, keypoints, confidence, THRESHOLD_PX)
    points = triangulate_rows(campus.P, choice.keypoints, choice.confidence)
    points = np.where(((choice.confidence > 0).sum(1) >= 2)[..., None], points, np.nan)
    return points[:, None]


def ring_rig(cameras: int) -> np.ndarray:
    """f32[C, 3, 4]: cameras 6 m from the centre, 2 m up, evenly around it, looking at 1 m above the centre."""
    K = np.array([[1000.0, 0, 960], [0, 1000.0, 540], [0, 0, 1]])
    P = []
    for angle in np.linspace(0, 2 * np.pi, cameras, endpoint=False):
        centre = np.array([6000 * np.cos(angle), 6000 * np.sin(angle), 2000.0])
        forward = (np.array([0, 0, 1000.0]) - centre) / np.linalg.norm(np.array([0, 0, 1000.0]) - centre)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        R = np.stack([right, np.cross(forward, right), forward])
        P.append(K @ np.hstack([R, -R @ centre[:, None]]))
    return np.array(P, np.float32)


def speed(instants: int = 100) -> None:
    """Instants per second of association and tracks at 2-6 people and 3-16 cameras (synthetic, 1 px noise)."""
    rng = np.random.default_rng(0)
    body = rng.uniform((-250, -150, 0), (250, 150, 1700), (14, 3))
    print(f"{'people':>6} {'cameras':>7} {'inst/s':>8}  ({instants} instants, 1 px noise, every person in every view)")
    for count in (2, 4, 6):
        for cameras in (3, 4, 8, 16):
            P = ring_rig(cameras)
            start_positions = rng.uniform(-2000, 2000, (count, 2))
            steps = np.arange(instants)[:, None, None] * rng.normal(0, 20, (1, count, 2))
            floor = np.concatenate([start_positions + steps, np.zeros((instants, count, 1))], -1)
            points = body + floor[:, :, None]  # [n, M, J, 3]
            h = np.einsum("cik,nmjk->ncmji", P, np.concatenate([points, np.ones((*points.shape[:-1], 1))], -1))
            keypoints = (h[..., :2] / h[..., 2:] + rng.normal(0, 1, h[..., :2].shape)).astype(np.float32)
            keypoints = np.take_along_axis(keypoints, rng.permuted(np.tile(np.arange(count), (instants, cameras, 1)), axis=-1)[..., None, None], 2)
            confidence = np.full(keypoints.shape[:-1], 0.9, np.float32)
            association.associate(P, keypoints[:1], confidence[:1], THRESHOLD_PX)  # compiled before timing
            start = time.perf_counter()
            found = association.associate(P, keypoints, confidence, THRESHOLD_PX)
            tracks.follow(found.points, found.present, LIMBS, tracks.TrackSettings(fps=FPS))
            print(f"{count:>6} {cameras:>7} {instants / (time.perf_counter() - start):>8.0f}")


# Without calibration -------------------------------------------------------------------------------------------
# The Campus 14 joints as a jaxpose skeleton, for calibration's limb-length scale (its names give the limbs).
CAMPUS_SKELETON_NAMES = ("RAnkle", "RKnee", "RHip", "LHip", "LKnee", "LAnkle", "RWrist", "RElbow", "RShoulder", "LShoulder",
                         "LElbow", "LWrist", "Neck", "HeadTop")  # fmt: skip
MATCH_THRESHOLD_PX = 4.0  # matching without a rig: the largest median epipolar distance (px) of one person's joints (360x288 images)


def campus_cameras(root: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Campus' calibration as (K f64[C, 3, 3] pixels, R f64[C, 3, 3], t f64[C, 3] mm), world to camera."""
    calibration = json.loads((root / "calibration.json").read_text())["cameras"]
    width, height = json.loads((root / "annotation_2d.json").read_text())["image_wh"]
    K, R, t = [], [], []
    for camera in CAMERAS:
        Tw = np.array(calibration[camera]["Tw"])  # camera to world, cm
        K.append(np.array(calibration[camera]["K"]) * np.array([[width], [height], [1]]))
        R.append(Tw[:3, :3].T)
        t.append(-Tw[:3, :3].T @ Tw[:3, 3] * 10.0)
    return np.array(K), np.array(R), np.array(t)


def recovered_rig(campus: Campus, K: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, seed: int):
    """The rig recovered from the simulated detections (Campus' intrinsics K given or None, its extrinsics not) as the
    rig loader recovers it from several people (`jaxpose.rig.recovered.people_rows`): the people matched across
    views without a rig, a first rig, everyone associated through it, the rig again, the second kept where it
    explains those rows at least as well (`explains_better`).  (the kept `jaxpose.calibration.Calibration`, both
    calibrations, the rows each was recovered from)."""
    from jaxpose.calibration import CalibrationConfig, RigDetections, calibrate
    from jaxpose.formats.rig_cameras import RigCalibration
    from jaxpose.rig.recovered import explains_better, people_rows
    from jaxpose.skeleton import Skeleton

    config = CalibrationConfig(seed=seed)
    # Parents only make the joint set a valid tree; calibration reads the limbs from the names.
    skeleton = Skeleton("campus14", CAMPUS_SKELETON_NAMES, (-1, 0, 1, 2, 3, 4, 7, 8, 12, 12, 9, 10, 2, 12), ())
    sizes = np.array([campus.image_size] * len(CAMERAS))
    rig, calibrations, rows = None, [], []
    for _ in range(2):
        xy, weight = people_rows(keypoints, confidence, None, rig, match_px=MATCH_THRESHOLD_PX)
        detections = RigDetections(xy, weight, CAMERAS, sizes, skeleton, K=K, source=f"Campus, seed {seed}")
        calibration = calibrate(detections, config)
        rig = RigCalibration(camera_names=CAMERAS, cameras=calibration.cameras, image_size=sizes, source="recovered", unit="mm")
        calibrations.append(calibration)
        rows.append(len(xy))
    kept = calibrations[1] if explains_better(calibrations[1], calibrations[0], detections) else calibrations[0]
    return kept, calibrations, rows


def without_calibration(root: Path, seeds: list[int], people_count: int | None, intrinsics: bool = True) -> None:
    """The Campus rig recovered from the people per seed: its error against Campus' calibration and the PCP
    of the association and tracks through it beside the calibrated run's.  The recovered world is Campus' only
    up to a similarity: the recovered cameras are moved onto the true ones by the similarity that fits them
    best (`jaxpose.calibration.compare_rigs`: rotation from the camera orientations, scale and offset from the
    centres), and the people are then triangulated through the moved cameras.  `intrinsics`: Campus' K given
    (else the focal lengths are estimated too, from an image-size guess)."""
    from jaxpose.calibration import compare_rigs

    campus = load_campus(root)
    K, R, t = campus_cameras(root)
    print(f"Campus without its calibration: {len(campus.truth)} frames, 3 cameras, intrinsics {'given' if intrinsics else 'estimated'};"
          f" detector {NOISE};"
          f" matching {MATCH_THRESHOLD_PX} px (the rig's rows associated at twice that), association {THRESHOLD_PX} px")  # fmt: skip
    print(f"{'seed':>4} {'rows from':<10} {'rows':>5} {'rot deg 0/1/2':>16} {'centre mm 0/1/2':>16} {'scale':>6} {'reproj px':>9} {'s':>5}"
          f" {'PCP given':>9} {'PCP recovered':>13} {'IDsw':>9}")  # fmt: skip
    given, recovered = [], []
    for seed in seeds:
        keypoints, confidence = simulate(campus, seed)
        calibration, (first, again), rows = recovered_rig(campus, K if intrinsics else None, keypoints, confidence, seed)
        before = compare_rigs(first.cameras.R, first.cameras.t, R, t)
        after = compare_rigs(again.cameras.R, again.cameras.t, R, t)
        error = compare_rigs(calibration.cameras.R, calibration.cameras.t, R, t)
        R_aligned = error.aligned_R
        t_aligned = -np.einsum("cij,cj->ci", R_aligned, error.aligned_centres)
        P = np.einsum("cij,cjk->cik", calibration.cameras.K, np.concatenate([R_aligned, t_aligned[..., None]], -1))
        scores = []
        for rig in (campus.P, P.astype(np.float32)):
            _, _, points, _ = several(dataclasses.replace(campus, P=rig), keypoints, confidence, people_count)
            identity = np.where(np.isfinite(points).all(-1).any(-1), np.arange(points.shape[1]), -1)
            scores.append(score(campus, points, identity))
        given.append(scores[0]["average"])
        recovered.append(scores[1]["average"])
        rotation = "/".join(f"{v:.2f}" for v in error.rotation_deg)
        centre = "/".join(f"{v:.0f}" for v in error.centre_mm)
        for name, count, rig_error, recovered_run in (("matched", rows[0], before, first), ("associated", rows[1], after, again)):
            focal = "" if intrinsics else "  focal " + "/".join(f"{v:+.1%}" for v in recovered_run.cameras.K[:, 0, 0] / K[:, 0, 0] - 1)
            print(f"{seed:>4} {name:<10} {count:>5} {'/'.join(f'{v:.2f}' for v in rig_error.rotation_deg):>16}"
                  f" {'/'.join(f'{v:.0f}' for v in rig_error.centre_mm):>16} {rig_error.scale_error:>+6.1%}"
                  f" {np.max(recovered_run.reprojection_median_px):>9.2f} {recovered_run.seconds:>5.0f}{focal}")  # fmt: skip
        print(f"{seed:>4} {'kept: ' + ('associated' if calibration is again else 'matched'):<16} {rotation:>16} {centre:>16}"
              f" {error.scale_error:>+6.1%} {'':>9} {'':>5} {scores[0]['average']:>9.1f} {scores[1]['average']:>13.1f}"
              f" {scores[0]['switches']:>4}/{scores[1]['switches']:<4}")  # fmt: skip
    print(f"mean average PCP over seeds: calibration given {np.mean(given):.1f}%, rig recovered from the people {np.mean(recovered):.1f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--campus", type=Path, default=CAMPUS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--people", type=int, default=None, help="the number of people, when known")
    parser.add_argument("--speed", action="store_true", help="instants per second at 2-6 people, 3-16 cameras instead")
    parser.add_argument("--without-calibration", action="store_true", help="the rig recovered from the people instead, beside the given one")
    parser.add_argument("--unknown-intrinsics", action="store_true", help="with --without-calibration: the focal lengths estimated too")
    args = parser.parse_args()
    if args.speed:
        speed()
        return
    if args.without_calibration:
        without_calibration(args.campus, args.seeds, args.people, intrinsics=not args.unknown_intrinsics)
        return
    campus = load_campus(args.campus)
    print(f"Campus: {len(campus.truth)} frames, 3 cameras; detector {NOISE}; association threshold {THRESHOLD_PX} px")
    header = f"{'seed':>4} {'path':<12} {'PCP 1':>6} {'PCP 2':>6} {'PCP 3':>6} {'avg':>6} {'MPJPE 1/2/3 mm':>18} {'IDsw':>5} {'false':>6} {'missed':>6} {'tracks':>6} {'left out':>8} {'inst/s':>7}"
    print(header)
    averages = {"several": [], "one person": []}
    for seed in args.seeds:
        keypoints, confidence = simulate(campus, seed)
        found, followed, track_points, seconds = several(campus, keypoints, confidence, args.people)
        for path, (points, extra) in {
            "several": (track_points,
                        f"{followed.count:>6} {found.unmatched:>8} {len(keypoints) / seconds:>7.0f}"),
            "one person": (one_person(campus, keypoints, confidence), f"{1:>6} {'':>8} {'':>7}"),
        }.items():
            # a track's slot is its identity, empty where it has no joint
            identity = np.where(np.isfinite(points).all(-1).any(-1), np.arange(points.shape[1]), -1)
            s = score(campus, points, identity)
            averages[path].append(s["average"])
            pcps = " ".join(f"{s['pcp'][i]:6.1f}" for i in sorted(s["pcp"]))
            mpjpe = "/".join(f"{s['mpjpe'][i]:.0f}" for i in sorted(s["mpjpe"]))
            print(f"{seed:>4} {path:<12} {pcps} {s['average']:6.1f} {mpjpe:>18} {s['switches']:>5} {s['false']:>6} {s['missed']:>6} {extra}")
    for path, values in averages.items():
        print(f"mean average PCP over seeds, {path}: {np.mean(values):.1f}%")


if __name__ == "__main__":
    main()
