"""Writers of small (or, for the benchmark, full-size) data trees in the real data sets' file formats.

Everything here follows docs/conventions.md and is implemented independently of the loaders (own
camera conventions, own projection formulas), so that loading a fixture and comparing it with the
values returned here checks the loaders against the documented formats.

Synthetic bodies: 32 (H36M), 15 (HumanEva) or 17 (3DHP) distinct random joint offsets around a
root that moves on a small circle near the world origin; cameras stand 4-5 m away looking at it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import numpy as np
import scipy.io

H36M_CAMERA_NAMES = ("54138969", "55011271", "58860488", "60457274")
# 32-joint mocap indices of the H36M_17 joints (docs/conventions.md), written out independently.
H36M_MOCAP_17 = (0, 1, 2, 3, 6, 7, 8, 12, 13, 14, 15, 17, 18, 19, 25, 26, 27)
# The Stacked Hourglass files' joint order, as mocap indices: RFoot, RKnee, RHip, LHip, LKnee,
# LFoot, Hip, Spine, Thorax, Head, RWrist, RElbow, RShoulder, LShoulder, LElbow, LWrist.
H36M_SH_FILE_MOCAP = (3, 2, 1, 6, 7, 8, 0, 12, 13, 15, 27, 26, 25, 17, 18, 19)

# Flags for experiment runs on these trees: a tiny network and one short epoch (the plumbing, not
# the accuracy), and the subjects of the tree `write_h36m_martinez_tree` writes by default.
TINY_TRAINING = [
    "--model.width", "32", "--train.epochs", "1", "--train.batch-size", "8", "--train.eval-batch-size", "256",
    "--run.no-progress", "--run.plot-samples", "0",
]  # fmt: skip
H36M_SUBJECTS = ["--data.train-subjects", "S1", "--data.test-subjects", "S9"]


# ----------------------------------------------------------------------------------------------
# Geometry


def look_at(centre, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-to-camera rotation (rows: image right, image down, optical axis) of a camera at
    `centre` looking at `target` in a z-up world."""
    forward = np.asarray(target, float) - np.asarray(centre, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])
    assert np.isclose(np.linalg.det(rotation), 1.0)
    return rotation


def synthetic_motion(rng: np.random.Generator, num_frames: int, num_joints: int, height: float = 900.0) -> np.ndarray:
    """f64[N, J, 3] world mm: distinct joint offsets (root first, at 0) turning and moving slowly."""
    offsets = rng.normal(0.0, 250.0, (num_joints, 3))
    offsets[0] = 0.0
    time = np.arange(num_frames) / 50.0
    yaw = 0.3 * time + rng.uniform(0, 2 * np.pi)
    cos, sin = np.cos(yaw), np.sin(yaw)
    rotation = np.zeros((num_frames, 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 1, 0], rotation[:, 1, 1] = cos, -sin, sin, cos
    rotation[:, 2, 2] = 1.0
    root = np.stack([400 * np.cos(0.2 * time), 400 * np.sin(0.2 * time), np.full(num_frames, height)], axis=-1)
    return root[:, None] + np.einsum("nij,kj->nki", rotation, offsets) + rng.normal(0, 5.0, (num_frames, num_joints, 3))


def ring_of_cameras(rng: np.random.Generator, count: int, radius: float, target=(0.0, 0.0, 900.0)) -> list[tuple]:
    """(R world-to-camera, centre) of `count` cameras on a ring, slightly perturbed."""
    cameras = []
    for index in range(count):
        azimuth = 2 * np.pi * (index + 0.5) / count + rng.uniform(-0.1, 0.1)
        centre = np.array([radius * np.cos(azimuth), radius * np.sin(azimuth), 1500.0 + rng.uniform(-200, 200)])
        cameras.append((look_at(centre, target), centre))
    return cameras


def h36m_project(camera: dict, points: np.ndarray) -> np.ndarray:
    """The cameras.h5 projection of docs/conventions.md, in float64: x_cam = R^T (X - T) with R, T
    as h5py reads them, the file's radial/tangential distortion, then pixel = f * x_d + c."""
    cam = (points - camera["T"].reshape(3)) @ camera["R"]  # (R^T (X - T))^T = (X - T)^T R
    x, y = cam[..., 0] / cam[..., 2], cam[..., 1] / cam[..., 2]
    k, p = camera["k"].reshape(3), camera["p"].reshape(2)
    r2 = x * x + y * y
    radial = 1 + k[0] * r2 + k[1] * r2**2 + k[2] * r2**3
    tangential = p[0] * y + p[1] * x
    x_d = x * (radial + tangential) + p[1] * r2
    y_d = y * (radial + tangential) + p[0] * r2
    f, c = camera["f"].reshape(2), camera["c"].reshape(2)
    return np.stack([f[0] * x_d + c[0], f[1] * y_d + c[1]], axis=-1)


def opencv_project(camera: dict, points: np.ndarray) -> np.ndarray:
    """OpenCV's Brown-Conrady projection, float64: x_cam = R X + t, dist = (k1, k2, p1, p2, k3)."""
    cam = points @ np.asarray(camera["R"]).T + np.asarray(camera["t"])
    x, y = cam[..., 0] / cam[..., 2], cam[..., 1] / cam[..., 2]
    k1, k2, p1, p2, k3 = camera["dist"]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    x_d = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    y_d = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = np.asarray(camera["K"])
    return np.stack([K[0, 0] * x_d + K[0, 1] * y_d + K[0, 2], K[1, 1] * y_d + K[1, 2]], axis=-1)


# ----------------------------------------------------------------------------------------------
# Human3.6M


def h36m_cameras(rng: np.random.Generator) -> list[dict]:
    """One subject's 4 cameras as cameras.h5 stores them (R with x_cam = R^T (X - T))."""
    cameras = []
    for name, (rotation, centre) in zip(H36M_CAMERA_NAMES, ring_of_cameras(rng, 4, 5000.0)):
        cameras.append(
            {
                "name": name,
                "R": rotation.T,  # h5py's R: x_cam = R^T (X - T)
                "T": centre.reshape(3, 1),
                "f": rng.uniform(1143, 1150, (2, 1)),
                "c": rng.uniform(500, 520, (2, 1)),
                "k": np.array([[-0.20], [0.24], [-0.005]]) + rng.normal(0, 0.005, (3, 1)),
                "p": rng.normal(0, 0.002, (2, 1)),
            }
        )
    return cameras


def write_h36m_cameras_h5(path: Path, cameras: dict[str, list[dict]]) -> None:
    """cameras.h5: subject{n}/camera{i}/{R, T, f, c, k, p, Name}, all float64 as in the real file
    (Name: the camera name's character codes as float64 [8, 1])."""
    with h5py.File(path, "w") as file:
        for subject, subject_cameras in cameras.items():
            for index, camera in enumerate(subject_cameras, start=1):
                group = file.create_group(f"subject{subject[1:]}/camera{index}")
                for field in ("R", "T", "f", "c", "k", "p"):
                    group.create_dataset(field, data=camera[field])
                codes = np.frombuffer(camera["name"].encode(), np.uint8).astype(np.float64).reshape(-1, 1)
                group.create_dataset("Name", data=codes)


@dataclasses.dataclass
class H36MFixture:
    """What was written: per subject the cameras (cameras.h5 convention) and per (subject,
    3D sequence name) the mocap f64[N, 32, 3] world mm."""

    root: Path
    cameras: dict[str, list[dict]]
    mocap: dict[tuple[str, str], np.ndarray]


H36M_SEQUENCES = ("Directions 1", "TakingPhoto", "WalkingDog 1", "Walking 1")


def write_h36m_martinez_tree(
    root: Path,
    subjects=("S1", "S9"),
    sequences=H36M_SEQUENCES,
    num_frames: int = 23,
    missing_views: dict[tuple[str, str], tuple[str, ...]] | None = None,
    orphan_2d: tuple[tuple[str, str], ...] = (),
    seed: int = 0,
    sh_mocap_joints: tuple[int, ...] = H36M_SH_FILE_MOCAP,
) -> H36MFixture:
    """h36m.zip layout: S*/MyPoses/3D_positions/<seq>.h5 (3D_positions f64[96, N]),
    S*/StackedHourglass/<seq with _>.<camera>.h5 (poses [N, 16, 2], here the exact projection of
    the mocap joints `sh_mocap_joints`: by default those of the SH file order), and cameras.h5.

    missing_views: (subject, sequence) -> cameras whose SH file is left out (like S11 Directions).
    orphan_2d: (subject, SH sequence name) written as SH files with no 3D file.
    """
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    cameras = {subject: h36m_cameras(rng) for subject in subjects}
    write_h36m_cameras_h5(root / "cameras.h5", cameras)
    mocap = {}
    for subject in subjects:
        poses_dir = root / subject / "MyPoses" / "3D_positions"
        sh_dir = root / subject / "StackedHourglass"
        poses_dir.mkdir(parents=True)
        sh_dir.mkdir(parents=True)
        # Trial lengths differ a little, as in the real data.
        lengths = num_frames + rng.integers(0, 3, len(sequences))
        for sequence, length in zip(sequences, lengths):
            points = synthetic_motion(rng, int(length), 32)
            mocap[subject, sequence] = points
            with h5py.File(poses_dir / f"{sequence}.h5", "w") as file:
                file.create_dataset("3D_positions", data=points.transpose(1, 2, 0).reshape(96, -1))
            left_out = (missing_views or {}).get((subject, sequence), ())
            for camera in cameras[subject]:
                if camera["name"] not in left_out:
                    pixels = h36m_project(camera, points[:, sh_mocap_joints])
                    _write_sh(sh_dir / f"{sequence.replace(' ', '_')}.{camera['name']}.h5", pixels)
    for subject, sequence in orphan_2d:
        for camera in cameras[subject]:
            pixels = h36m_project(camera, synthetic_motion(rng, num_frames, 32)[:, H36M_SH_FILE_MOCAP])
            _write_sh(root / subject / "StackedHourglass" / f"{sequence}.{camera['name']}.h5", pixels)
    return H36MFixture(root=root, cameras=cameras, mocap=mocap)


def _write_sh(path: Path, pixels: np.ndarray) -> None:
    """A Stacked Hourglass file: poses float64 [N, 16, 2], as the real files."""
    with h5py.File(path, "w") as file:
        file.create_dataset("poses", data=pixels.astype(np.float64))


def h36m_canonical_name(sequence: str) -> str:
    """VideoPose3D's sequence naming: TakingPhoto -> Photo, WalkingDog -> WalkDog."""
    return sequence.replace("TakingPhoto", "Photo").replace("WalkingDog", "WalkDog")


def write_h36m_videopose3d_files(
    root: Path,
    fixture: H36MFixture,
    detector_file: str = "data_2d_h36m_cpn_ft_h36m_dbb.npz",
    extra_2d_frames: int = 0,
    drop_views: dict[tuple[str, str], int] | None = None,
) -> None:
    """data_3d_h36m.npz (positions_3d: subject -> sequence -> f32[N, 32, 3] METRES) and a 2D
    file (positions_2d: subject -> sequence -> list of 4 f32[N + extra, 17, 2], camera order
    H36M_CAMERA_NAMES; metadata) from a Martinez fixture, with VideoPose3D's sequence names.
    The 2D are the exact projections; `extra_2d_frames` more frames (repeats of the last one)
    mimic detection files longer than the mocap.  drop_views: (subject, 3D name) -> number of
    trailing cameras left out of the list.
    """
    root.mkdir(parents=True, exist_ok=True)
    positions_3d, positions_2d = {}, {}
    for (subject, sequence), points in fixture.mocap.items():
        name = h36m_canonical_name(sequence)
        positions_3d.setdefault(subject, {})[name] = (points / 1000.0).astype(np.float32)
        padded = np.concatenate([points, np.repeat(points[-1:], extra_2d_frames, axis=0)])
        joints = padded[:, H36M_MOCAP_17]
        views = [h36m_project(camera, joints).astype(np.float32) for camera in fixture.cameras[subject]]
        drop = (drop_views or {}).get((subject, sequence), 0)
        positions_2d.setdefault(subject, {})[name] = views[: len(views) - drop]
    symmetry = [[4, 5, 6, 11, 12, 13], [1, 2, 3, 14, 15, 16]]
    metadata = {"layout_name": "h36m", "num_joints": 17, "keypoints_symmetry": symmetry}
    np.savez_compressed(root / "data_3d_h36m.npz", positions_3d=positions_3d)
    np.savez_compressed(root / detector_file, positions_2d=positions_2d, metadata=metadata)


# ----------------------------------------------------------------------------------------------
# HumanEva-I


HUMANEVA_CAMERA_NAMES = ("C1", "C2", "C3")
HUMANEVA_SEQUENCES = {
    "Train": ("Walk 1 chunk0", "Walk 1 chunk1", "Jog 1 chunk0", "Box 1 chunk0"),
    "Validate": ("Walk 1 chunk0", "Jog 1 chunk0", "Gestures 1 chunk0"),
}


def humaneva_cameras(rng: np.random.Generator) -> list[dict]:
    """Three 640x480 cameras in our convention (x_cam = R x + t) with OpenCV distortion."""
    cameras = []
    for name, (rotation, centre) in zip(HUMANEVA_CAMERA_NAMES, ring_of_cameras(rng, 3, 4000.0)):
        focal = rng.uniform(750, 770)
        cameras.append(
            {
                "name": name,
                "K": [
                    [focal, 0.0, 320.0 + rng.uniform(-5, 5)],
                    [0.0, focal * 1.01, 240.0 + rng.uniform(-5, 5)],
                    [0.0, 0.0, 1.0],
                ],
                "R": rotation.tolist(),
                "t": (-rotation @ centre).tolist(),
                "dist": [-0.3 + rng.normal(0, 0.01), 0.1, 0.001, -0.0005, 0.0],
                "image_size": [640, 480],
            }
        )
    return cameras


@dataclasses.dataclass
class HumanEvaFixture:
    root: Path
    cameras_path: Path
    cameras: dict[str, list[dict]]  # "S1" -> cameras (our convention, JSON fields)
    poses: dict[tuple[str, str], np.ndarray]  # ("Train/S1", sequence) -> f64[N, 15, 3] mm, with the invalid frames
    invalid: dict[tuple[str, str], np.ndarray]  # the frame numbers made invalid


def write_humaneva_files(
    root: Path, subjects=("S1", "S2"), num_frames: int = 12, source: str = "detectron_pt_coco", seed: int = 1
) -> HumanEvaFixture:
    """data_3d_humaneva15.npz (METRES), data_2d_humaneva15_<source>.npz (3 views, exact projections)
    and cameras.json (a jaxpose camera file).  Frame 2 of every sequence has NaN markers and frame
    5 an all-zero joint (both in 3D and, projected, in 2D), as lost markers look in the real files."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    cameras = {subject: humaneva_cameras(rng) for subject in subjects}
    document = {"format": "jaxpose-cameras", "version": 1, "distortion_model": "opencv", "subjects": cameras}
    cameras_path = root / "cameras.json"
    cameras_path.write_text(json.dumps(document))
    positions_3d, positions_2d, poses, invalid = {}, {}, {}, {}
    for partition, sequences in HUMANEVA_SEQUENCES.items():
        for subject in subjects:
            key = f"{partition}/{subject}"
            for sequence in sequences:
                points = synthetic_motion(rng, num_frames, 15, height=1000.0)
                points[2, 4] = np.nan
                points[5, 9] = 0.0
                poses[key, sequence] = points
                invalid[key, sequence] = np.array([2, 5])
                positions_3d.setdefault(key, {})[sequence] = (points / 1000.0).astype(np.float32)
                views = [opencv_project(camera, points).astype(np.float32) for camera in cameras[subject]]
                positions_2d.setdefault(key, {})[sequence] = views
    np.savez_compressed(root / "data_3d_humaneva15.npz", positions_3d=positions_3d)
    metadata = {"layout_name": "humaneva15", "num_joints": 15}
    np.savez_compressed(root / f"data_2d_humaneva15_{source}.npz", positions_2d=positions_2d, metadata=metadata)
    return HumanEvaFixture(root=root, cameras_path=cameras_path, cameras=cameras, poses=poses, invalid=invalid)


# ----------------------------------------------------------------------------------------------
# MPI-INF-3DHP test set


# Our MPI_INF_3DHP_17 joints, as indices into the file's joint order (0 head_top, 1 neck,
# 2 right_shoulder, 3 right_elbow, 4 right_wrist, 5 left_shoulder, 6 left_elbow, 7 left_wrist,
# 8 right_hip, 9 right_knee, 10 right_ankle, 11 left_hip, 12 left_knee, 13 left_ankle, 14 pelvis,
# 15 spine, 16 head).
MPI_FILE_INDEX_OF_OURS = (14, 8, 9, 10, 11, 12, 13, 15, 1, 16, 0, 5, 6, 7, 2, 3, 4)


@dataclasses.dataclass
class MpiFixture:
    root: Path
    annot2: dict[str, np.ndarray]  # sequence -> f64[N, 17, 2], file joint order, all frames
    annot3: dict[str, np.ndarray]  # f64[N, 17, 3] camera mm
    univ_annot3: dict[str, np.ndarray]
    valid: dict[str, np.ndarray]  # bool[N]
    activity: dict[str, np.ndarray]  # int[N] codes 1..7
    K: dict[str, np.ndarray]


def write_mpi_inf_3dhp_test_set(
    root: Path,
    sequences: dict[str, str] | None = None,
    num_frames: int = 9,
    K: dict[str, np.ndarray] | None = None,
    seed: int = 2,
) -> MpiFixture:
    """TS*/annot_data.mat with annot2, annot3, univ_annot3, valid_frame, activity_annotation.

    sequences: name -> "v7.3" (HDF5-based, written through h5py with a MATLAB userblock and
    MATLAB's reversed axis order) or "v5" (scipy.io.savemat).  MATLAB shapes: annot2 2x17x1xN,
    annot3 / univ_annot3 3x17x1xN, valid_frame and activity_annotation 1xN.
    annot2 is the pinhole projection of annot3 through K[sequence].
    """
    sequences = sequences or {"TS1": "v7.3", "TS5": "v5"}
    rng = np.random.default_rng(seed)
    fixture = MpiFixture(root, {}, {}, {}, {}, {}, {})
    for index, (name, kind) in enumerate(sequences.items()):
        count = num_frames + index
        univ = synthetic_motion(rng, count, 17, height=0.0)[:, :, [0, 2, 1]] * [1, -1, 1] + [0, 0, 4000.0]
        annot3 = univ * 1.05
        matrix = np.asarray(K[name]) if K else np.array([[1500.0, 0, 1017.0], [0, 1500.5, 1043.0], [0, 0, 1]])
        projected = annot3 @ matrix.T
        annot2 = projected[..., :2] / projected[..., 2:]
        valid = np.ones(count, bool)
        valid[[1, count - 2]] = False
        activity = rng.integers(1, 8, count)
        matlab = {  # MATLAB axis order
            "annot2": annot2.transpose(2, 1, 0)[:, :, None, :],
            "annot3": annot3.transpose(2, 1, 0)[:, :, None, :],
            "univ_annot3": univ.transpose(2, 1, 0)[:, :, None, :],
            "valid_frame": valid.astype(np.float64)[None, :],
            "activity_annotation": activity.astype(np.float64)[None, :],
        }
        folder = root / name
        folder.mkdir(parents=True, exist_ok=True)
        if kind == "v7.3":
            _write_mat73(folder / "annot_data.mat", matlab)
        else:
            scipy.io.savemat(folder / "annot_data.mat", matlab)
        fixture.annot2[name], fixture.annot3[name], fixture.univ_annot3[name] = annot2, annot3, univ
        fixture.valid[name], fixture.activity[name], fixture.K[name] = valid, activity, matrix
    return fixture


def _write_mat73(path: Path, variables: dict[str, np.ndarray]) -> None:
    """A MATLAB v7.3 file: HDF5 behind a 512-byte userblock holding MATLAB's text header; h5py
    sees every array with its axes reversed, as MATLAB writes them."""
    with h5py.File(path, "w", userblock_size=512) as file:
        for name, array in variables.items():
            file.create_dataset(name, data=np.ascontiguousarray(np.transpose(array)))
    with open(path, "r+b") as handle:
        header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created by: jaxpose test fixtures HDF5 schema 1.00 ."
        handle.write(header.ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
