"""Several people: association across views (`jaxpose.rig.association`), tracks over time
(`jaxpose.rig.tracks`), scored on Campus by the field's measure beside the one-person path
(`jaxpose.rig.people.choose`), on synthetic projects whose truth is known, and timed.

    python -m benchmarks.people [--campus ../shared/data/multiperson/campus] [--seeds 0 1 2] [--without-calibration]
    python -m benchmarks.people --synthetic 2 3 4 5 [--seeds 0 1 2] [--frames 300]
    python -m benchmarks.people --speed
    python -m benchmarks.people --pose2sim [--venv ~/.cache/jaxpose-peers/venv] [--repeats 5]

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

`--synthetic`: the example project (`SYNTHETIC`: jaxpose.synthetic's default detector, false detections,
occlusion, two people passing 0.5 m apart, the last leaving and coming back) written and read back as files;
association precision and recall over cross-view pairs of detections (`pair_precision_recall`), tracks,
identity switches, false and missed people as above, and each person's MPJPE beside the same person
reconstructed alone (`alone`).  `--speed`: instants per second at 2-6 people and 3-16 cameras.  `--pose2sim`:
beside Pose2Sim's person association on its multi-person demo, run in the peers' environment
(`benchmarks/peers.py` makes it).

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
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from jaxpose.camera import projection_matrices
from jaxpose.formats import keypoint_files
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.formats.rig_folder import read_ground_truth
from jaxpose.rig import association, geometry, people, tracks
from jaxpose.rig.geometry import triangulate_rows
from jaxpose.skeleton import COCO_17
from jaxpose.synthetic import ExampleProjectConfig, write_rig_project

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
CAMERA_COUNTS = (3, 4, 8, 16)  # the speed table's rigs
THRESHOLD_PX = 15.0  # association: the images are 360x288, the people 60-120 px tall
SYNTHETIC_LIMBS = np.array([(j, p) for j, p in enumerate(COCO_17.parents) if p >= 0])
SYNTHETIC_MIRROR = COCO_17.flip_permutation()


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


def pair_with_truth(truth: list, points: np.ndarray, identity: np.ndarray) -> dict:
    """truth: per instant, dict id -> f32[J, 3] mm; points f32[N, M, J, 3], identity int[N, M] (-1: no output
    person) -> per id the nearest output slot at each of its instants ("nearest": list of (instant, slot or
    None)), the one-to-one pairs within `PAIRING_MM` ("paired": list of (instant, id, slot)), and the counts
    of identity switches, false and missed people of the module docstring."""
    nearest, paired_all = {}, []
    last = {}
    switches = false = missed = 0
    for n, frame in enumerate(truth):
        if not frame:
            continue
        out = np.flatnonzero(identity[n] >= 0)
        truth_ids = list(frame)
        distance = np.full((len(truth_ids), len(out)), np.inf)
        for a, i in enumerate(truth_ids):
            for b, m in enumerate(out):
                distance[a, b] = np.nanmean(np.linalg.norm(points[n, m] - frame[i], axis=-1))
            found = len(out) and np.isfinite(distance[a]).any()
            nearest.setdefault(i, []).append((n, out[np.nanargmin(distance[a])] if found else None))
        rows, cols = linear_sum_assignment(np.where(np.isfinite(distance), distance, 1e9)) if len(out) else ([], [])
        paired = [(r, c) for r, c in zip(rows, cols) if distance[r, c] <= PAIRING_MM]
        false += len(out) - len(paired)
        missed += len(truth_ids) - len(paired)
        for r, c in paired:
            track = identity[n, out[c]]
            switches += truth_ids[r] in last and last[truth_ids[r]] != track
            last[truth_ids[r]] = track
            paired_all.append((n, truth_ids[r], out[c]))
    return {"nearest": nearest, "paired": paired_all, "switches": int(switches), "false": int(false), "missed": int(missed)}


def score(campus: Campus, points: np.ndarray, identity: np.ndarray) -> dict:
    """points f32[N, M, J, 3], identity int[N, M] (-1: no output person) -> the scores of the module docstring;
    PCP and MPJPE of each ground-truth person against the output person nearest to it, as the field scores Campus."""
    pairs = pair_with_truth(campus.truth, points, identity)
    ids = sorted(pairs["nearest"])
    correct = {i: [] for i in ids}
    errors = {i: [] for i in ids}
    for i in ids:
        for n, slot in pairs["nearest"][i]:
            if slot is None:
                correct[i].append(np.zeros(10, bool))
            else:
                correct[i].append(pcp(points[n, slot], campus.truth[n][i]))
                errors[i].append(np.nanmean(np.linalg.norm(points[n, slot] - campus.truth[n][i], axis=-1)))
    per_person = {i: 100 * np.mean(correct[i]) for i in ids}
    return {
        "pcp": per_person,
        "average": float(np.mean(list(per_person.values()))),
        "mpjpe": {i: float(np.mean(errors[i])) for i in ids},
        "switches": pairs["switches"],
        "false": pairs["false"],
        "missed": pairs["missed"],
    }


def several(campus: Campus, keypoints: np.ndarray, confidence: np.ndarray, people_count: int | None) -> tuple:
    start = time.perf_counter()
    found = association.associate(campus.P, keypoints, confidence, THRESHOLD_PX, FLIP)
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


# The synthetic projects (`jaxpose.synthetic`'s example project with several people, its default detector):
# the people 0.5 m apart at least, the first two passing each other 0.5 m apart, the last leaving and coming
# back, false detections in 10% of each view's frames, occlusion; 4 cameras in sync, 50 fps, a 4 m square
# (5 people walking 0.5 m apart fit in it).
SYNTHETIC = ExampleProjectConfig(
    people=2, recordings=1, frames_per_recording=300, cameras=4, desync_camera=-1, second_person_rate=0.0, motions=("walking",),
    capture_area=4000.0, min_distance=500.0, pass_each_other=500.0, false_people_rate=0.1, occlusion=True, absent_frames=60,
)  # fmt: skip
SYNTHETIC_THRESHOLD_PX = 20.0  # 1920x1080 images, people 300-500 px tall, the detector's noise 3-8 px a joint


@dataclasses.dataclass(frozen=True)
class Scene:
    """A synthetic project's recording as the association takes it, and its truth."""

    P: np.ndarray  # f32[C, 3, 4] undistorted pixels from world mm
    keypoints: np.ndarray  # f32[N, C, K, J, 2] undistorted pixels, each view's detections in file order
    confidence: np.ndarray  # f32[N, C, K, J]
    who: np.ndarray  # int[N, C, K]: the person of each detection, -1 a false one, -2 padding
    truth: np.ndarray  # f32[N, P, J, 3] world mm, NaN while a person is out of the scene
    fps: float


def synthetic_scene(config: ExampleProjectConfig) -> Scene:
    """Write `config`'s project (one recording, cameras in sync) to a temporary folder and read it back as
    the loader does: OpenPose JSON, calibration.toml (undistorted here), ground_truth.npz, and
    example_truth.json's people_order (who each listed detection is)."""
    with tempfile.TemporaryDirectory() as folder:
        root = write_rig_project(Path(folder) / "project", config)
        name = config.recording_names[0]
        calibration = read_rig_calibration(root / "calibration.toml", unit="m")
        order = json.loads((root / "example_truth.json").read_text())["recordings"][name]["people_order"]
        views = [keypoint_files.read_openpose_folder(root / name / f"{camera}_json", progress=False, workers=1) for camera in config.camera_names]
        truth = read_ground_truth(root / name / "ground_truth.npz").points
    N, C = config.frames_per_recording, config.cameras
    K = max(view.keypoints.shape[1] for view in views)
    J = views[0].keypoints.shape[2]
    keypoints = np.zeros((N, C, K, J, 2), np.float32)
    confidence = np.zeros((N, C, K, J), np.float32)
    who = np.full((N, C, K), -2, np.int64)
    for c, (camera, view) in enumerate(zip(config.camera_names, views)):
        k = view.keypoints.shape[1]
        keypoints[:, c, :k] = geometry.undistort_views(calibration, camera, view.keypoints)
        confidence[:, c, :k] = view.scores
        for n, codes in enumerate(order[camera]):
            who[n, c, : len(codes)] = [max(code, -1) for code in codes]
    P = np.asarray(projection_matrices(calibration.cameras), np.float32)
    return Scene(P, keypoints, confidence, who, np.asarray(truth[:, :, :J], np.float32), config.fps)


def pair_precision_recall(found: association.Association, who: np.ndarray) -> tuple[float, float]:
    """Association precision and recall over cross-view pairs of detections at the same instant: a pair put
    in one person is right when both are the same real person; the true pairs are every two views' detections
    of the same real person (one seen by a single view has none)."""
    N, C, K = who.shape
    right = claimed = 0
    for n, m in np.argwhere(found.present):
        codes = [who[n, c, k] for c, k in enumerate(found.detection[n, m]) if k >= 0]
        for a in range(len(codes)):
            for b in range(a + 1, len(codes)):
                claimed += 1
                right += codes[a] == codes[b] >= 0
    per_person = np.stack([(who == p).any(-1).sum(-1) for p in range(who.max() + 1)], -1)  # [N, P] views seeing p
    true = int((per_person * (per_person - 1) // 2).sum())
    return right / max(claimed, 1), right / max(true, 1)


def alone(scene: Scene) -> np.ndarray:
    """Each person reconstructed alone: the association of their own detections only (`Scene.who`), as the
    recording of that person alone would be, f32[N, P, J, 3] (NaN where the association finds nobody)."""
    count = scene.truth.shape[1]
    own = scene.who[..., None] == np.arange(count)  # [N, C, K, P]
    index = np.argmax(own, 2)  # [N, C, P]
    seen = own.any(2)
    N, C = index.shape[:2]
    xy = scene.keypoints[np.arange(N)[:, None, None], np.arange(C)[:, None], index]  # [N, C, P, J, 2]
    weight = np.where(seen[..., None], scene.confidence[np.arange(N)[:, None, None], np.arange(C)[:, None], index], 0.0)
    points = np.full(scene.truth.shape, np.nan, np.float32)
    for p in range(count):
        found = association.associate(scene.P, xy[:, :, p : p + 1], weight[:, :, p : p + 1], SYNTHETIC_THRESHOLD_PX, SYNTHETIC_MIRROR)
        points[:, p] = np.where(found.present[:, :1, None, None], found.points[:, :1], np.nan)[:, 0]  # most views first
    return points


def synthetic_scores(scene: Scene, people_count: int | None = None) -> dict:
    """Association precision and recall, tracks and identity switches, and each person's MPJPE (mm, per-instant
    triangulation of the associated detections) beside the same person's alone on the same instants."""
    start = time.perf_counter()
    found = association.associate(scene.P, scene.keypoints, scene.confidence, SYNTHETIC_THRESHOLD_PX, SYNTHETIC_MIRROR)
    followed = tracks.follow(found.points, found.present, SYNTHETIC_LIMBS, tracks.TrackSettings(fps=scene.fps, people=people_count))
    seconds = time.perf_counter() - start
    precision, recall = pair_precision_recall(found, scene.who)
    truth = [{p: scene.truth[n, p] for p in range(scene.truth.shape[1]) if np.isfinite(scene.truth[n, p]).all()} for n in range(len(scene.truth))]
    pairs = pair_with_truth(truth, found.points, followed.identity)
    single = alone(scene)
    errors = {p: ([], []) for p in range(scene.truth.shape[1])}
    for n, p, slot in pairs["paired"]:
        both = np.isfinite(found.points[n, slot]).all(-1) & np.isfinite(single[n, p]).all(-1)
        errors[p][0].extend(np.linalg.norm(found.points[n, slot] - scene.truth[n, p], axis=-1)[both])
        errors[p][1].extend(np.linalg.norm(single[n, p] - scene.truth[n, p], axis=-1)[both])
    return {
        "precision": precision, "recall": recall, "tracks": followed.count, "switches": pairs["switches"],
        "false": pairs["false"], "missed": pairs["missed"], "unmatched": found.unmatched,
        "mpjpe": {p: float(np.mean(e[0])) for p, e in errors.items()}, "alone": {p: float(np.mean(e[1])) for p, e in errors.items()},
        "instants_per_s": len(scene.truth) / seconds,
    }  # fmt: skip


def synthetic(seeds: Sequence[int], counts: Sequence[int], frames: int) -> None:
    print(f"synthetic projects: {SYNTHETIC}; association threshold {SYNTHETIC_THRESHOLD_PX} px")
    print(f"{'people':>6} {'seed':>4} {'precision':>9} {'recall':>7} {'tracks':>6} {'IDsw':>5} {'false':>6} {'missed':>6} {'left out':>8} "
          f"{'max |MPJPE - alone| mm':>22}  MPJPE per person (alone) mm")  # fmt: skip
    for count in counts:
        for seed in seeds:
            config = dataclasses.replace(SYNTHETIC, people=count, seed=seed, frames_per_recording=frames, absent_frames=frames // 5)
            s = synthetic_scores(synthetic_scene(config))
            gap = max(abs(s["mpjpe"][p] - s["alone"][p]) for p in s["mpjpe"])
            each = " ".join(f"{s['mpjpe'][p]:.1f} ({s['alone'][p]:.1f})" for p in sorted(s["mpjpe"]))
            print(f"{count:>6} {seed:>4} {100 * s['precision']:>8.2f}% {100 * s['recall']:>6.2f}% {s['tracks']:>6} {s['switches']:>5} "
                  f"{s['false']:>6} {s['missed']:>6} {s['unmatched']:>8} {gap:>22.2f}  {each}")  # fmt: skip


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


def speed(instants: int = 100, repeats: int = 3) -> None:
    """Instants per second of association and tracks at 2-6 people and 3-16 cameras (synthetic, 1 px noise):
    the median of `repeats` calls after one that compiles, how the time grows with the cameras (the
    exponent of a power law fitted over 3-16 cameras: 1 is linear), and the instants at which every person
    was found with a detection in every view."""
    import os

    rng = np.random.default_rng(0)
    body = rng.uniform((-250, -150, 0), (250, 150, 1700), (14, 3))
    print(f"{instants} instants, 1 px noise, every person in every view; median of {repeats} calls; "
          f"{os.cpu_count()} cores ({len(os.sched_getaffinity(0))} usable)")  # fmt: skip
    print(f"{'people':>6} {'cameras':>7} {'inst/s':>8} {'ms/inst':>8} {'ms/inst/camera':>14} {'all found':>11}")
    for count in (2, 4, 6):
        times = []
        for cameras in CAMERA_COUNTS:
            P = ring_rig(cameras)
            start_positions = rng.uniform(-2000, 2000, (count, 2))
            steps = np.arange(instants)[:, None, None] * rng.normal(0, 20, (1, count, 2))
            floor = np.concatenate([start_positions + steps, np.zeros((instants, count, 1))], -1)
            points = body + floor[:, :, None]  # [n, M, J, 3]
            h = np.einsum("cik,nmjk->ncmji", P, np.concatenate([points, np.ones((*points.shape[:-1], 1))], -1))
            keypoints = (h[..., :2] / h[..., 2:] + rng.normal(0, 1, h[..., :2].shape)).astype(np.float32)
            keypoints = np.take_along_axis(keypoints, rng.permuted(np.tile(np.arange(count), (instants, cameras, 1)), axis=-1)[..., None, None], 2)
            confidence = np.full(keypoints.shape[:-1], 0.9, np.float32)
            association.associate(P, keypoints, confidence, THRESHOLD_PX, FLIP)  # compiles
            calls = []
            for _ in range(repeats):
                start = time.perf_counter()
                found = association.associate(P, keypoints, confidence, THRESHOLD_PX, FLIP)
                tracks.follow(found.points, found.present, LIMBS, tracks.TrackSettings(fps=FPS))
                calls.append(time.perf_counter() - start)
            times.append(float(np.median(calls)))
            per = 1000 * times[-1] / instants
            everyone = 100 * np.mean((found.detection >= 0).all(-1).sum(-1) == count)  # each person with all views
            print(f"{count:>6} {cameras:>7} {instants / times[-1]:>8.0f} {per:>8.2f} {per / cameras:>14.3f} {everyone:>10.1f}%")
        exponent = np.polyfit(np.log(CAMERA_COUNTS), np.log(times), 1)[0]
        print(f"{count:>6} people: time ~ cameras^{exponent:.2f} over {CAMERA_COUNTS[0]}-{CAMERA_COUNTS[-1]} cameras")


POSE2SIM_DEMO = CAMPUS.parents[1] / "formats" / "openpose-json" / "pose2sim_demo_multiperson_body25b"
POSE2SIM_CALIBRATION = CAMPUS.parents[1] / "formats" / "pose2sim-calib-toml" / "pose2sim_demo_Calib_qualisys.toml"
PEERS_VENV = Path.home() / ".cache" / "jaxpose-peers" / "venv"
DEMO_LIMBS = np.array([[5, 7], [7, 9], [6, 8], [8, 10], [11, 13], [13, 15], [12, 14], [14, 16]])  # BODY_25B's arms and legs
# Run by the peers' python (imports nothing of jaxpose): Pose2Sim's multi-person association (`associate_all`,
# its Demo_MultiPerson Config.toml, pose_model BODY_25B) on a trial folder, timed per call, as JSON on stdout.
POSE2SIM_SCRIPT = """
import json, logging, sys, time
from pathlib import Path
import rtoml, Pose2Sim
from Pose2Sim.personAssociation import associate_all
logging.disable(logging.CRITICAL)
trial, repeats = Path(sys.argv[1]), int(sys.argv[2])
config = rtoml.load(Path(Pose2Sim.__file__).parent / 'Demo_MultiPerson' / 'Config.toml')
config['project']['project_dir'] = str(trial)
config['project']['multi_person'] = True
config['pose']['pose_model'] = 'BODY_25B'
(trial / 'Config.toml').write_text(rtoml.dumps(config))  # Pose2Sim finds the trial by its Config.toml
seconds = []
for _ in range(repeats):
    start = time.perf_counter()
    associate_all(config)
    seconds.append(time.perf_counter() - start)
print(json.dumps({'seconds': seconds, 'version': Pose2Sim.__version__ if hasattr(Pose2Sim, '__version__') else '?'}))
"""


def demo_inputs(demo: Path, calibration_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose2Sim's multi-person demo as the association takes it: P f32[4, 3, 4], keypoints (undistorted) and
    confidence of its four views (read from its OpenPose JSON)."""
    calibration = read_rig_calibration(calibration_path, unit="m")
    views = [keypoint_files.read_openpose_folder(demo / f"cam0{c}_json", progress=False, workers=1) for c in range(1, 5)]
    N, K, J = len(views[0].frames), max(v.keypoints.shape[1] for v in views), views[0].keypoints.shape[2]
    keypoints = np.zeros((N, 4, K, J, 2), np.float32)
    confidence = np.zeros((N, 4, K, J), np.float32)
    for c, (name, view) in enumerate(zip(calibration.camera_names, views)):
        keypoints[:, c, : view.keypoints.shape[1]] = geometry.undistort_views(calibration, name, view.keypoints)
        confidence[:, c, : view.keypoints.shape[1]] = view.scores
    return np.asarray(projection_matrices(calibration.cameras), np.float32), keypoints, confidence


def versus_pose2sim(demo: Path, calibration: Path, venv: Path, repeats: int) -> None:
    """jaxpose's association and tracks beside Pose2Sim's person association on Pose2Sim's multi-person demo
    (4 cameras, 100 frames), one process after the other on this machine: the first call, then the median of
    `repeats`.  jaxpose's time with and without reading the JSON files (Pose2Sim's includes reading and
    writing them)."""
    import os
    import shutil
    import subprocess
    import sys

    def jaxpose_call(read: bool) -> float:
        start = time.perf_counter()
        P, keypoints, confidence = demo_inputs(demo, calibration) if read else inputs
        found = association.associate(P, keypoints, confidence)
        followed = tracks.follow(found.points, found.present, DEMO_LIMBS, tracks.TrackSettings(fps=30.0))
        assert followed.count >= 2
        return time.perf_counter() - start

    inputs = demo_inputs(demo, calibration)
    frames = inputs[1].shape[0]
    first = jaxpose_call(True)
    with_reading = [jaxpose_call(True) for _ in range(repeats)]
    association_only = [jaxpose_call(False) for _ in range(repeats)]
    python = venv / "bin" / "python"
    print(f"Pose2Sim's multi-person demo: {frames} frames, 4 cameras; {os.cpu_count()} cores ({len(os.sched_getaffinity(0))} usable); {sys.version.split()[0]}")
    print(f"{'method':<52} {'first s':>8} {'median s':>9} {'frames/s':>9}")
    rows = [("jaxpose: read JSON + associate + tracks", first, with_reading), ("jaxpose: associate + tracks (detections in memory)", association_only[0], association_only)]
    if not python.exists():
        print(f"{venv}: no peers' environment (benchmarks/peers.py makes it); Pose2Sim not run")
    else:
        with tempfile.TemporaryDirectory() as folder:
            trial = Path(folder) / "trial"
            (trial / "calibration").mkdir(parents=True)
            shutil.copy(calibration, trial / "calibration" / "Calib.toml")
            for c in range(1, 5):
                shutil.copytree(demo / f"cam0{c}_json", trial / "pose" / f"cam0{c}_json")
            done = subprocess.run([str(python), "-c", POSE2SIM_SCRIPT, str(trial), str(repeats + 1)], capture_output=True, text=True)
        if done.returncode:
            print(f"Pose2Sim failed: {done.stderr.strip().splitlines()[-1]}")
        else:
            seconds = json.loads(done.stdout.strip().splitlines()[-1])["seconds"]
            pose2sim = float(np.median(seconds[1:]))
            rows.append(("Pose2Sim 0.10 personAssociation (multi_person)", seconds[0], seconds[1:]))
    for name, first_s, times in rows:
        print(f"{name:<52} {first_s:>8.3f} {np.median(times):>9.3f} {frames / np.median(times):>9.0f}")
    if python.exists() and not done.returncode:
        for name, _, times in rows[:2]:
            print(f"Pose2Sim / {name.split(':')[1].strip()}: {pose2sim / np.median(times):.0f}x (medians)")


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
    parser.add_argument("--synthetic", type=int, nargs="*", metavar="PEOPLE", help="the synthetic projects of these many people instead")
    parser.add_argument("--frames", type=int, default=SYNTHETIC.frames_per_recording, help="frames of each synthetic project")
    parser.add_argument("--pose2sim", action="store_true", help="beside Pose2Sim's person association on its multi-person demo instead")
    parser.add_argument("--venv", type=Path, default=PEERS_VENV, help="the peers' environment (benchmarks/peers.py)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls after the first (--pose2sim)")
    parser.add_argument("--without-calibration", action="store_true", help="the rig recovered from the people instead, beside the given one")
    parser.add_argument("--unknown-intrinsics", action="store_true", help="with --without-calibration: the focal lengths estimated too")
    args = parser.parse_args()
    if args.speed:
        speed()
        return
    if args.pose2sim:
        versus_pose2sim(POSE2SIM_DEMO, POSE2SIM_CALIBRATION, args.venv, args.repeats)
        return
    if args.synthetic is not None:
        synthetic(args.seeds, args.synthetic or [2, 3, 4, 5], args.frames)
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
