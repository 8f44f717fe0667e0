"""Human3.6M: the 4-camera multi-view training and test data of the paper.

Two file layouts are read (docs/conventions.md has the checked facts):

- "martinez", the h36m.zip of Martinez et al.::

      <data_dir>/S1/MyPoses/3D_positions/<Sequence>.h5          3D_positions f64[96, N], world mm
      <data_dir>/S1/StackedHourglass/<Sequence_>.<camera>.h5     poses f[N, 16, 2], pixels
      <data_dir>/cameras.h5

- "videopose3d", the files of VideoPose3D's data preparation::

      <data_dir>/data_3d_h36m.npz                      positions_3d: subject -> sequence -> f32[N, 32, 3] m
      <data_dir>/data_2d_h36m_cpn_ft_h36m_dbb.npz      positions_2d: subject -> sequence -> 4 x f32[N, 17, 2]
      plus a calibration: cameras.h5 or a jaxpose camera file (`cameras_path`)

2D sources (`detections`): "sh" (the Stacked Hourglass files of the Martinez layout; 16 joints,
skeleton `H36M_16`), "cpn" (VideoPose3D's CPN npz in `data_dir`; 17 joints), "gt" (the 3D ground
truth projected through the real cameras with their distortion; 17 joints), or the path of any
VideoPose3D-style 2D npz with 17 joints in `H36M_17` order.  The 3D and 2D sources are matched by
subject and sequence, so the layouts mix (e.g. Martinez 3D with CPN 2D).

The views of every rig are in the order `CAMERA_NAMES` (VideoPose3D's order); 2D npz lists must
use that order.  Sequence names differ between sources ("Walking 1" / "Walking_1", "TakingPhoto" /
"Photo", "WalkingDog" / "WalkDog"); they are matched by (canonical action, trial number), and the
labels keep the 3D file's full sequence name.  A sequence that misses some cameras' 2D (S11
Directions has 3 of the 4 SH files) keeps its other views; the missing views get confidence 0, so
training uses the views that exist and evaluation skips only the missing ones.  Such sequences,
3D sequences without any 2D and 2D sequences with no 3D counterpart are named in warnings.  Frames
are down-sampled from 50 fps by keeping every `train_stride`-th (training subjects) or
`test_stride`-th (all other subjects) frame, starting at frame 0.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from jaxpose.camera import Cameras
from jaxpose.formats.camera_file import read_calibration, select_views
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_h5_dataset
from jaxpose.datasets.sequences import CapturedSequence, PlannedSequence, SequencePlan, build_dataset, stack_views
from jaxpose.datasets.videopose3d import load_positions, subject_poses3d, subject_views2d
from jaxpose.skeleton import H36M_16, H36M_17, H36M_32_TO_17

TRAIN_SUBJECTS = ("S1", "S5", "S6", "S7", "S8")
TEST_SUBJECTS = ("S9", "S11")
CAMERA_NAMES = ("54138969", "55011271", "58860488", "60457274")

# 2D files of VideoPose3D's data preparation, by short detector name.
DETECTION_FILES = {"cpn": "data_2d_h36m_cpn_ft_h36m_dbb.npz"}
POSES_3D_FILE = "data_3d_h36m.npz"

# Joint order of the Stacked Hourglass files, in H36M_16's joint names.
SH_FILE_JOINTS = (
    "RFoot", "RKnee", "RHip", "LHip", "LKnee", "LFoot", "Hip", "Spine", "Thorax", "Head",
    "RWrist", "RElbow", "RShoulder", "LShoulder", "LElbow", "LWrist",
)
_SH_TO_OURS = np.array([SH_FILE_JOINTS.index(name) for name in H36M_16.joint_names])
_MOCAP_INDEX = dict(zip(H36M_17.joint_names, H36M_32_TO_17))

# Action names that differ between subjects / file sets, mapped to one name.
ACTION_ALIASES = {"TakingPhoto": "Photo", "WalkingDog": "WalkDog"}

Reader = Callable[[], np.ndarray]  # reads one sequence's array when called
# 2D of one subject: sequence key -> (sequence name in the 2D source, camera name -> reader of
# f[N, J, 2] pixels in our joint order).
Sources2D = dict[tuple[str, str], tuple[str, dict[str, Reader]]]


def load_h36m(
    data_dir: str | Path,
    *,
    layout: str = "auto",
    detections: str | Path = "sh",
    subjects: Sequence[str] = TRAIN_SUBJECTS + TEST_SUBJECTS,
    train_stride: int = 5,
    test_stride: int = 5,
    cameras_path: str | Path | None = None,
    progress: bool = True,
) -> MultiViewDataset:
    """Load Human3.6M as a `MultiViewDataset` (4 views, world mm, pixels, confidence 1).

    layout: "auto" (Martinez when `S*/MyPoses/3D_positions` exists, else VideoPose3D), "martinez"
    or "videopose3d".  detections: "sh" (-> `H36M_16`), "cpn", "gt", or a 2D npz path (-> `H36M_17`).
    subjects: any of `TRAIN_SUBJECTS + TEST_SUBJECTS`; `test_stride` applies to `TEST_SUBJECTS`,
    `train_stride` to the others.  cameras_path: cameras.h5 or a jaxpose camera file (.json);
    default `<data_dir>/cameras.h5`.  Labels: "subject", "action" (canonical, e.g. "Photo"),
    "sequence" (the 3D source's full name, e.g. "TakingPhoto 1"), "frame" (frame number at 50 fps).
    Raises `DataFormatError` for missing or malformed files, before returning anything.
    """
    data_dir = Path(data_dir)
    if not data_dir.is_dir():
        raise DataFormatError(data_dir, "the Human3.6M data folder", "no such folder")
    if min(train_stride, test_stride) < 1:
        raise ValueError(f"strides must be >= 1, got train_stride={train_stride}, test_stride={test_stride}")
    named = ("sh", "gt", *DETECTION_FILES)
    if detections not in named and not str(detections).endswith(".npz"):
        raise ValueError(f"detections must be one of {named} or the path of a 2D .npz file, got {detections!r}")
    layout = _resolve_layout(data_dir, layout)
    skeleton = H36M_16 if detections == "sh" else H36M_17
    joints3d = np.array([_MOCAP_INDEX[name] for name in skeleton.joint_names])
    rigs = subject_rigs(Path(cameras_path) if cameras_path else data_dir / "cameras.h5", subjects)
    read_3d = functools.partial(_martinez_3d, data_dir)
    if layout == "videopose3d":
        path = data_dir / POSES_3D_FILE
        positions = load_positions(path, "positions_3d", "VideoPose3D 3D poses")
        read_3d = functools.partial(_videopose3d_3d, path, positions)
    if detections == "gt":
        read_2d = None
    elif detections == "sh":
        read_2d = functools.partial(_stacked_hourglass_2d, data_dir)
    else:
        path = data_dir / DETECTION_FILES[detections] if detections in DETECTION_FILES else Path(detections)
        positions = load_positions(path, "positions_2d", "VideoPose3D 2D detections")
        read_2d = functools.partial(_npz_2d, path, positions)

    plan = SequencePlan("Human3.6M", CAMERA_NAMES)
    for subject in subjects:
        sequences3d = read_3d(subject)
        by_key = _index_by_key(sequences3d, f"{data_dir} subject {subject} 3D sequences")
        sources2d = {} if read_2d is None else read_2d(subject)
        plan.skip_2d_without_3d(subject, [sources2d[key][0] for key in sorted(set(sources2d) - set(by_key))])
        for key, name in sorted(by_key.items(), key=lambda item: item[1]):
            views = None if read_2d is None else sources2d.get(key, (None, {}))[1]
            plan.add(subject, name, sequences3d[name], views)
    sequences = plan.sequences(data_dir, f"Human3.6M sequences of subjects {list(subjects)}")

    recordings = [
        _read_recording(sequence, test_stride if sequence.subject in TEST_SUBJECTS else train_stride, joints3d)
        for sequence in tqdm(sequences, desc="Human3.6M", unit="seq", disable=not progress)
    ]
    return build_dataset(skeleton, recordings, rigs)


def sequence_action(name: str) -> str:
    """Canonical action of a sequence name: "Walking 1" -> "Walking", "TakingPhoto_1" -> "Photo"."""
    return _sequence_key(name)[0]


def _sequence_key(name: str) -> tuple[str, str]:
    """(canonical action, trial number or "") of a 3D or 2D sequence name."""
    base, number = re.fullmatch(r"(.*?)(?:[ _](\d+))?", name.strip()).groups()
    return ACTION_ALIASES.get(base, base), number or ""


def _index_by_key(names, where: str) -> dict[tuple[str, str], str]:
    index = {}
    for name in names:
        key = _sequence_key(name)
        if key in index:
            raise DataFormatError(where, "one sequence per action and trial", f"both {index[key]!r} and {name!r}")
        index[key] = name
    return index


def _resolve_layout(data_dir: Path, layout: str) -> str:
    if layout in ("martinez", "videopose3d"):
        return layout
    if layout != "auto":
        raise ValueError(f"layout must be 'auto', 'martinez' or 'videopose3d', got {layout!r}")
    if any(data_dir.glob("S*/MyPoses/3D_positions")):
        return "martinez"
    if (data_dir / POSES_3D_FILE).exists():
        return "videopose3d"
    raise DataFormatError(
        data_dir,
        f"S<n>/MyPoses/3D_positions/*.h5 (h36m.zip of Martinez et al.) or {POSES_3D_FILE} (VideoPose3D)",
        f"only {sorted(p.name for p in data_dir.iterdir())[:20]}",
    )


def subject_rigs(path: Path, subjects: Sequence[str]) -> dict[str, Cameras]:
    """Each subject's 4 cameras in `CAMERA_NAMES` order, from cameras.h5 or a camera file."""
    calibration = read_calibration(path)
    rigs = {}
    for subject in subjects:
        rigs[subject] = select_views(calibration, path, subject, CAMERA_NAMES)
    return rigs


def _list_h5(folder: Path, expected: str) -> list[Path]:
    files = sorted(folder.glob("*.h5"))
    if not files:
        raise DataFormatError(folder, expected, "no such folder" if not folder.is_dir() else "no .h5 files")
    return files


def _read_mocap(path: Path) -> np.ndarray:
    """A Martinez 3D file: 3D_positions f[96, N] -> f[N, 32, 3] world mm."""
    data = read_h5_dataset(path, "3D_positions", "Human3.6M 3D poses")
    if data.ndim != 2 or data.shape[0] != 96:
        raise DataFormatError(path, "dataset 3D_positions of shape (96, N)", f"shape {data.shape}")
    return data.reshape(32, 3, -1).transpose(2, 0, 1)


def _read_stacked_hourglass(path: Path) -> np.ndarray:
    """A Stacked Hourglass file: poses f[N, 16, 2] in the file's joint order -> H36M_16 order."""
    poses = read_h5_dataset(path, "poses", "Stacked Hourglass detections")
    if poses.ndim != 3 or poses.shape[1:] != (16, 2):
        raise DataFormatError(path, "dataset poses of shape (N, 16, 2)", f"shape {poses.shape}")
    return poses[:, _SH_TO_OURS]


def _martinez_3d(data_dir: Path, subject: str) -> dict[str, Reader]:
    files = _list_h5(data_dir / subject / "MyPoses" / "3D_positions", "3D pose files <Sequence>.h5")
    return {path.stem: functools.partial(_read_mocap, path) for path in files}


def _videopose3d_3d(path: Path, positions: Mapping, subject: str) -> dict[str, Reader]:
    poses = subject_poses3d(path, positions, subject, num_joints=32)
    return {name: functools.partial(np.multiply, array, 1000.0) for name, array in poses.items()}  # m -> mm


def _stacked_hourglass_2d(data_dir: Path, subject: str) -> Sources2D:
    folder = data_dir / subject / "StackedHourglass"
    sources: Sources2D = {}
    for path in _list_h5(folder, "Stacked Hourglass files <Sequence>.<camera>.h5"):
        sequence, _, camera = path.stem.rpartition(".")
        if not sequence:
            raise DataFormatError(path, "a file name <Sequence>.<camera>.h5", repr(path.name))
        name, views = sources.setdefault(_sequence_key(sequence), (sequence, {}))
        if sequence != name:
            raise DataFormatError(folder, "one file name per sequence and camera", f"both {name!r} and {sequence!r}")
        views[camera] = functools.partial(_read_stacked_hourglass, path)
    return sources


def _npz_2d(path: Path, positions: Mapping, subject: str) -> Sources2D:
    sources: Sources2D = {}
    for name, views in subject_views2d(path, positions, subject, CAMERA_NAMES, num_joints=17).items():
        key = _sequence_key(name)
        if key in sources:
            raise DataFormatError(
                f"{path} positions_2d[{subject!r}]",
                "one sequence per action and trial",
                f"both {sources[key][0]!r} and {name!r}",
            )
        sources[key] = (name, {camera: functools.partial(np.asarray, array) for camera, array in views.items()})
    return sources


def _read_recording(sequence: PlannedSequence, stride: int, joints3d: np.ndarray) -> CapturedSequence:
    """Read one sequence, every frame (the samples are every `stride`-th), and check that its 2D covers its 3D."""
    subject, name = sequence.subject, sequence.name
    points = sequence.poses3d()
    frames = np.arange(len(points), dtype=np.int32)
    keypoints = confidence = None
    if sequence.views is not None:
        read = {camera: reader() for camera, reader in sequence.views.items()}
        keypoints, confidence = stack_views(f"Human3.6M {subject} {name!r}", read, CAMERA_NAMES, len(points), frames)
    return CapturedSequence(
        subject=subject,
        action=sequence_action(name),
        sequence=name,
        frames=frames,
        points3d=points[:, joints3d].astype(np.float32),
        keypoints2d=keypoints,
        confidence=confidence,
        kept=np.arange(0, len(points), stride),
    )
