"""Human3.6M S1 as a project of two sessions, through the rig loader without calibration
(`python -m experiments.sessions_study --h36m-project PROJECT`; see that module's docstring).

The project is `experiments.rig_from_h36m --no-calibration --moved PATTERN ...`'s: the recordings the
patterns name were filmed through S1's rig with every camera moved (`moved_rig.npz` holds that rig),
the others through cameras.h5's.  Loaded with the development protocol (every 5th instant; the first
trial of each action trains, the others are held out), the sessions found are compared with the truth:
- each session's recovered rig against the true rig of its recordings, after one similarity alignment
  (`jaxpose.calibration.compare_rigs`): rotation (deg) and centre (mm) error per camera, and the
  focal length (mean of fx, fy) and principal point errors;
- the held-out recordings' detections triangulated through the session's recovered rig, and after one
  similarity alignment (with scale) per session of all its triangulated joints onto the motion capture,
  their world MPJPE; beside it the triangulation through the true cameras (no alignment, and after one
  similarity per session) and through one rig recovered from every recording (--data.no-find-sessions).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

import numpy as np

from experiments.h36m import first_trials
from jaxpose.calibration import compare_rigs
from jaxpose.camera import Cameras, projection_matrices, undistort_points
from jaxpose.datasets.h36m import sequence_action
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.formats.rig_folder import DETECTIONS_NPZ, GROUND_TRUTH_NPZ
from jaxpose.rig.geometry import triangulate_rows
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.recordings import recording_folders
from jaxpose.rotations import similarity

MOVED_RIG_NPZ = "moved_rig.npz"  # experiments.rig_from_h36m's
STRIDE = 5  # the development protocol's


def h36m_study(project: pathlib.Path, data_dir: pathlib.Path, recovery_frames: int, one_rig: bool) -> dict:
    names = [folder.name for folder in recording_folders(project, ())]
    train = first_trials(np.array(["S1"] * len(names)), np.array([sequence_action(name) for name in names]), np.array(names))
    held_out = tuple(name for name, first in zip(names, train) if not first)
    truth = _true_rigs(project, data_dir, names)
    config = RigProjectConfig(
        root=project, train_stride=STRIDE, validation_stride=STRIDE, validation_recordings=held_out, recovery_frames=recovery_frames
    )
    evaluation = {name: _held_out_recording(project / name) for name in held_out}
    true_sessions = {}
    for name in names:
        true_sessions.setdefault(truth[name][0], []).append(name)
    results = {}
    for label, find in (("sessions found", True), ("one rig", False)) if one_rig else (("sessions found", True),):
        started = time.perf_counter()
        loaded = load_rig_project(dataclasses.replace(config, find_sessions=find), progress=False)
        seconds = time.perf_counter() - started
        print(f"\n## {label}: {len(loaded.sessions)} sessions, loaded in {seconds:.0f} s ({loaded.prepared})")
        print("| session | recordings | true rigs of its recordings | re-projection (px) |\n|---|---|---|---|")
        for session in loaded.sessions:
            rigs = sorted({truth[name][0] for name in session.recordings})
            print(f"| {session.name} | {len(session.recordings)}: {', '.join(session.recordings)} | {', '.join(rigs)} | {session.reprojection_px:.2f} |")
        rows = []
        for true_name, members in true_sessions.items():
            session = next(s for s in loaded.sessions if members[0] in s.recordings)
            cameras = session.calibration.cameras
            true = truth[members[0]][1]
            comparison = compare_rigs(
                np.asarray(cameras.R, np.float64), np.asarray(cameras.t, np.float64), np.asarray(true.R, np.float64), np.asarray(true.t, np.float64)
            )
            recovered_mpjpe = _session_mpjpe(cameras, [evaluation[name] for name in members if name in evaluation], align=True)
            true_mpjpe = _session_mpjpe(true, [evaluation[name] for name in members if name in evaluation], align=False)
            true_aligned = _session_mpjpe(true, [evaluation[name] for name in members if name in evaluation], align=True)
            rows.append((true_name, session.name, comparison, recovered_mpjpe, true_mpjpe, true_aligned, cameras.K, true.K))
        print(
            "\n| true rig | recovered as | focal error per camera | principal point error per camera (px) | rotation error per camera (deg)"
            " | centre error per camera (mm) | scale error | triangulation MPJPE, recovered, one similarity (mm) | true cameras (mm)"
            " | true cameras, one similarity (mm) |\n|---|---|---|---|---|---|---|---|---|---|"
        )
        for true_name, session_name, comparison, recovered_mpjpe, true_mpjpe, true_aligned, K, true_K in rows:
            focal = np.asarray(K)[:, [0, 1], [0, 1]].mean(-1) / np.asarray(true_K)[:, [0, 1], [0, 1]].mean(-1) - 1.0
            centre = np.linalg.norm(np.asarray(K)[:, :2, 2] - np.asarray(true_K)[:, :2, 2], axis=-1)
            print(
                f"| {true_name} | {session_name} | {' '.join(f'{v:+.1%}' for v in focal)} | {' '.join(f'{v:.1f}' for v in centre)}"
                f" | {' '.join(f'{v:.2f}' for v in comparison.rotation_deg)}"
                f" | {' '.join(f'{v:.1f}' for v in comparison.centre_mm)} | {comparison.scale_error:+.2%}"
                f" | {recovered_mpjpe:.1f} | {true_mpjpe:.1f} | {true_aligned:.1f} |"
            )
        results[label] = rows
    return results


def _true_rigs(project: pathlib.Path, data_dir: pathlib.Path, names) -> dict[str, tuple[str, Cameras]]:
    """Recording -> (the name of its true rig, its cameras: Human3.6M's lens, mm)."""
    h36m = read_rig_calibration(data_dir / "cameras.h5", subject="S1")
    moved, moved_names = None, ()
    if (project / MOVED_RIG_NPZ).is_file():
        with np.load(project / MOVED_RIG_NPZ, allow_pickle=False) as file:
            if tuple(file["camera_names"].tolist()) != tuple(h36m.camera_names):
                raise SystemExit(f"{project / MOVED_RIG_NPZ}: cameras {file['camera_names']} are not cameras.h5's {h36m.camera_names}")
            moved = Cameras(K=file["K"], R=file["R"], t=file["t"], dist=file["dist"], distortion_model=str(file["distortion_model"]))
            moved_names = tuple(file["recordings"].tolist())
    return {name: ("moved", moved) if name in moved_names else ("cameras.h5", h36m.cameras) for name in names}


def _held_out_recording(folder: pathlib.Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(distorted keypoints [N, C, J, 2], confidence [N, C, J], mocap [N, J, 3] mm) at every STRIDE-th frame."""
    with np.load(folder / DETECTIONS_NPZ, allow_pickle=False) as detections, np.load(folder / GROUND_TRUTH_NPZ, allow_pickle=False) as truth:
        if not np.array_equal(detections["frames"], truth["frames"]):
            raise SystemExit(f"{folder}: the detections' and the ground truth's frames differ")
        rows = slice(None, None, STRIDE)
        return detections["keypoints"][rows], detections["confidence"][rows], truth["points3d"][rows]


def _triangulate(cameras: Cameras, keypoints: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """The detections undistorted through each camera's lens and triangulated (world of `cameras`)."""
    undistorted = np.stack([np.asarray(undistort_points(cameras[c], keypoints[:, c]), np.float32) for c in range(keypoints.shape[1])], 1)
    P = np.asarray(projection_matrices(cameras.without_distortion()), np.float32)
    return triangulate_rows(P, undistorted, confidence, method="normal")


def _session_mpjpe(cameras: Cameras, recordings, align: bool) -> float:
    """World MPJPE (mm) of the recordings triangulated through `cameras`, after one similarity alignment
    (with scale) of all their joints onto the motion capture where `align`."""
    points, targets = [], []
    for keypoints, confidence, target in recordings:
        triangulated = _triangulate(cameras, keypoints, confidence)
        usable = ((confidence > 0).sum(1) >= 2) & np.isfinite(target).all(-1) & np.isfinite(triangulated).all(-1)
        points.append(triangulated[usable].astype(np.float64))
        targets.append(target[usable].astype(np.float64))
    points, targets = np.concatenate(points), np.concatenate(targets)
    if align:
        s, R, t = similarity(points, targets)
        points = s * points @ R.T + t
    return float(np.linalg.norm(points - targets, axis=-1).mean())
