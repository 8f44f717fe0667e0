"""Bad inputs end in a clear error, never in a crash inside h5py/numpy/JAX or in a silent NaN.

Hypothesis damages the files of every real-data format (empty, truncated, garbage, overwritten
bytes), replaces arrays inside well-formed files (NaN, inf, strings, complex, wrong shapes, no
frames), turns a camera around, and corrupts `MultiViewBatch` fields.  The contract: loading and
then preparing training data (pseudo-labels, `validate_batch`) either raises `DataFormatError` /
`BatchValidationError` with a message naming the problem, or yields data that is finite and valid.
The files users bring for a rig (issue 34): cameras named differently by the calibration and the
folders, and what must be a one-line refusal naming the culprit that leaves every file as it was (a frame
file name that is not UTF-8, near-singular intrinsics, two cameras at one centre).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import pickle
import re
import shutil

import h5py
import jax.numpy as jnp
import numpy as np
import paths
import pytest
import scipy.io
from calibration_writers import aniposelib_style_toml, synthetic_rig, write_easymocap
from fixtures_real_data import (
    write_h36m_martinez_tree,
    write_h36m_videopose3d_files,
    write_humaneva_files,
    write_mpi_inf_3dhp_test_set,
)
from geometry_helpers import exact_batch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from experiments import rig as rig_experiment
from jaxpose.training import pseudo_labelling
from jaxpose.data import BatchValidationError, validate_batch
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.datasets.h36m import load_h36m
from jaxpose.datasets.humaneva import load_humaneva
from jaxpose.datasets.mpi_inf_3dhp import load_mpi_inf_3dhp_test
from jaxpose.formats import file_cache, intrinsics
from jaxpose.rig.config import CACHE_DIR
from jaxpose.formats.rig_cameras import RigCalibration, check_intrinsics
from jaxpose.formats.camera_file import save_cameras
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project

# Few examples keep the suite fast; HARDEN_EXAMPLES=500 explores more (it passed so when written).
SMALL = settings(
    max_examples=int(os.environ.get("HARDEN_EXAMPLES", 12)),
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)

H36M_3D = "h36m/S1/MyPoses/3D_positions/Walking 1.h5"
H36M_SH = "h36m/S1/StackedHourglass/Walking_1.55011271.h5"
H36M_CAMERAS = "h36m/cameras.h5"
VP_3D = "h36m_vp/data_3d_h36m.npz"
VP_2D = "h36m_vp/data_2d_h36m_cpn_ft_h36m_dbb.npz"
HE_3D = "humaneva/data_3d_humaneva15.npz"
HE_2D = "humaneva/data_2d_humaneva15_detectron_pt_coco.npz"
HE_CAMERAS = "humaneva/cameras.json"
MPI_V73 = "mpi/TS1/annot_data.mat"
MPI_V5 = "mpi/TS5/annot_data.mat"
LOADER_OF = {
    H36M_3D: "h36m",
    H36M_SH: "h36m",
    H36M_CAMERAS: "h36m",
    VP_3D: "h36m_vp",
    VP_2D: "h36m_vp",
    HE_3D: "humaneva",
    HE_2D: "humaneva",
    HE_CAMERAS: "humaneva",
    MPI_V73: "mpi",
    MPI_V5: "mpi",
}


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """One small tree per format; tests damage a file and restore it afterwards."""
    root = tmp_path_factory.mktemp("formats")
    sequences = ("Directions 1", "Walking 1")
    fixture = write_h36m_martinez_tree(root / "h36m", subjects=("S1",), sequences=sequences, num_frames=8)
    write_h36m_videopose3d_files(root / "h36m_vp", fixture)
    shutil.copy(root / H36M_CAMERAS, root / "h36m_vp")
    write_humaneva_files(root / "humaneva", subjects=("S1",), num_frames=8)
    write_mpi_inf_3dhp_test_set(root / "mpi", num_frames=6)
    return root


def _load(root, loader: str):
    if loader == "h36m":
        return load_h36m(root / "h36m", subjects=("S1",), progress=False)
    if loader == "h36m_vp":
        return load_h36m(root / "h36m_vp", layout="videopose3d", detections="cpn", subjects=("S1",), progress=False)
    if loader == "humaneva":
        return load_humaneva(root / "humaneva", detections="detectron_pt_coco", subjects=("Train/S1",), progress=False)
    return load_mpi_inf_3dhp_test(root / "mpi", sequences=("TS1", "TS5"), progress=False)


def _load_and_prepare(root, loader: str):
    """Load, then what training does before the first step: pseudo-labels and `validate_batch`."""
    data = _load(root, loader)
    if isinstance(data, MultiViewDataset):
        labelled = pseudo_labelling.label(data)
        validate_batch(labelled.batch(np.arange(len(labelled))))
        arrays = [labelled.samples.keypoints2d, labelled.samples.target3d, labelled.samples.pseudo3d, labelled.samples.pseudo3d_weight]
    else:
        arrays = [data.keypoints2d, data.univ3d, data.camera3d]
    for array in arrays:
        assert np.isfinite(array).all(), "a silent NaN/inf"
    return data


def _expect_clear_error_or_valid_data(root, loader: str, names: str | None = None):
    """The contract of this module; `names` (the damaged file) must appear in a DataFormatError's
    message, which says by construction where, what was expected and what was found."""
    try:
        return _load_and_prepare(root, loader)
    except DataFormatError as error:
        assert names is None or names in str(error), str(error)
    except BatchValidationError:
        pass


@contextlib.contextmanager
def _restored(path):
    original = path.read_bytes()
    try:
        yield
    finally:
        path.write_bytes(original)


damages = st.one_of(
    st.tuples(st.just("empty")),
    st.tuples(st.just("truncate"), st.floats(0.0, 0.98)),
    st.tuples(st.just("garbage"), st.binary(min_size=1, max_size=512)),
    st.tuples(st.just("overwrite"), st.floats(0.0, 0.95), st.binary(min_size=4, max_size=64)),
)


def _damage(data: bytes, damage: tuple) -> bytes:
    kind = damage[0]
    if kind == "empty":
        return b""
    if kind == "truncate":
        return data[: int(len(data) * damage[1])]
    if kind == "garbage":
        return damage[1]
    start = int(len(data) * damage[1])
    return data[:start] + damage[2] + data[start + len(damage[2]) :]


@SMALL
@given(target=st.sampled_from(sorted(LOADER_OF)), damage=damages)
def test_damaged_files(root, target, damage):
    path = root / target
    with _restored(path):
        path.write_bytes(_damage(path.read_bytes(), damage))
        _expect_clear_error_or_valid_data(root, LOADER_OF[target], path.name)


# ----------------------------------------------------------------------------------------------
# Well-formed files with bad arrays inside


def _bad_values(array: np.ndarray, kind: str, position: float):
    """`array` turned bad in one way."""
    flat_index = np.unravel_index(int(position * (array.size - 1)), array.shape) if array.size else None
    if kind in ("nan", "inf"):
        bad = np.array(array, dtype=np.float64)
        bad[flat_index] = np.nan if kind == "nan" else -np.inf
        return bad
    if kind == "string":
        return array.astype("S8")
    if kind == "complex":
        return array.astype(np.complex64)
    if kind == "no frames":
        return array[:0] if array.ndim else array
    if kind == "drop axis":
        return array[..., 0]
    if kind == "extra axis":
        return array[..., None]
    return array[..., :-1]  # "short last axis"


BAD_KINDS = ["nan", "inf", "string", "complex", "no frames", "drop axis", "extra axis", "short last axis"]


def _rewrite_h5(path, dataset: str, kind: str, position: float, matlab: bool = False) -> None:
    with h5py.File(path, "a") as file:
        array = file[dataset][()]
        array = np.transpose(array) if matlab else array  # v7.3 stores MATLAB's axes reversed
        bad = _bad_values(array, kind, position)
        del file[dataset]
        file[dataset] = np.transpose(bad) if matlab else bad


def _rewrite_npz(path, key: str, item_path: tuple, kind: str, position: float) -> None:
    with np.load(path, allow_pickle=True) as archive:
        contents = {name: archive[name] for name in archive.files}
    tree = contents[key].item()
    node = tree
    for step in item_path[:-1]:
        node = node[step]
    node[item_path[-1]] = _bad_values(np.asarray(node[item_path[-1]]), kind, position)
    contents[key] = np.array(pickle.loads(pickle.dumps(tree)), dtype=object)
    np.savez(path, **contents)


def _rewrite_mat_v5(path, variable: str, kind: str, position: float) -> None:
    variables = {k: v for k, v in scipy.io.loadmat(path).items() if not k.startswith("__")}
    variables[variable] = _bad_values(variables[variable], kind, position)
    scipy.io.savemat(path, variables)


ARRAYS = {
    "h36m 3D_positions": (H36M_3D, lambda p, k, x: _rewrite_h5(p, "3D_positions", k, x)),
    "h36m SH poses": (H36M_SH, lambda p, k, x: _rewrite_h5(p, "poses", k, x)),
    "h36m camera T": (H36M_CAMERAS, lambda p, k, x: _rewrite_h5(p, "subject1/camera2/T", k, x)),
    "h36m camera f": (H36M_CAMERAS, lambda p, k, x: _rewrite_h5(p, "subject1/camera3/f", k, x)),
    "vp 3D": (VP_3D, lambda p, k, x: _rewrite_npz(p, "positions_3d", ("S1", "Walking 1"), k, x)),
    "vp 2D": (VP_2D, lambda p, k, x: _rewrite_npz(p, "positions_2d", ("S1", "Walking 1", 2), k, x)),
    "humaneva 3D": (HE_3D, lambda p, k, x: _rewrite_npz(p, "positions_3d", ("Train/S1", "Jog 1 chunk0"), k, x)),
    "humaneva 2D": (HE_2D, lambda p, k, x: _rewrite_npz(p, "positions_2d", ("Train/S1", "Box 1 chunk0", 1), k, x)),
    "mpi v7.3 annot2": (MPI_V73, lambda p, k, x: _rewrite_h5(p, "annot2", k, x, matlab=True)),
    "mpi v7.3 valid_frame": (MPI_V73, lambda p, k, x: _rewrite_h5(p, "valid_frame", k, x, matlab=True)),
    "mpi v5 univ_annot3": (MPI_V5, lambda p, k, x: _rewrite_mat_v5(p, "univ_annot3", k, x)),
    "mpi v5 activity": (MPI_V5, lambda p, k, x: _rewrite_mat_v5(p, "activity_annotation", k, x)),
}


@SMALL
@given(array=st.sampled_from(sorted(ARRAYS)), kind=st.sampled_from(BAD_KINDS), position=st.floats(0.0, 1.0))
def test_bad_arrays_in_well_formed_files(root, array, kind, position):
    target, rewrite = ARRAYS[array]
    path = root / target
    with _restored(path):
        rewrite(path, kind, position)
        _expect_clear_error_or_valid_data(root, LOADER_OF[target])


@pytest.mark.parametrize("loader", sorted(set(LOADER_OF.values())))
def test_undamaged_trees_load_and_validate(root, loader):
    """The other branch of the contract is reachable: the undamaged files give valid data."""
    assert len(_load_and_prepare(root, loader)) > 0


def test_a_camera_turned_around_is_named(root):
    path = root / HE_CAMERAS
    with _restored(path):
        document = json.loads(path.read_text())
        camera = document["subjects"]["S1"][1]
        R, t = np.array(camera["R"]), np.array(camera["t"])
        centre = -R.T @ t
        turned = np.diag([-1.0, 1.0, -1.0]) @ R  # half a turn about the camera's y axis: faces away
        camera["R"], camera["t"] = turned.tolist(), (-turned @ centre).tolist()
        path.write_text(json.dumps(document))
        with pytest.raises(BatchValidationError, match=r"behind camera 1: it faces away; check the camera convention"):
            _load_and_prepare(root, "humaneva")


# ----------------------------------------------------------------------------------------------
# MultiViewBatch fields


@pytest.fixture(scope="module")
def good():
    batch, _ = exact_batch(np.random.default_rng(0), 3, 3, 5)
    return batch.replace(pseudo3d_weight=jnp.ones((3, 5)))


FIELDS = ["keypoints2d", "confidence", "pseudo3d", "pseudo3d_weight", "target3d", "K", "R", "t"]


@SMALL
@given(
    field=st.sampled_from(FIELDS), kind=st.sampled_from([*BAD_KINDS, "int", "object", "none"]), position=st.floats(0, 1)
)
def test_bad_batch_fields_are_named(good, field, kind, position):
    holder = good.cameras if field in ("K", "R", "t") else good
    array = np.asarray(getattr(holder, field))
    if kind == "int":
        bad = array.astype(np.int32)
    elif kind == "object":
        bad = np.full(array.shape, None, dtype=object)
    elif kind == "none":
        bad = None
    else:
        bad = _bad_values(array, kind, position)
    if field in ("K", "R", "t"):
        batch = good.replace(cameras=good.cameras.replace(**{field: bad}))
    else:
        batch = good.replace(**{field: bad})
    optional = field in ("pseudo3d_weight", "target3d") and bad is None
    if optional:
        validate_batch(batch)  # optional fields may be absent
        return
    with pytest.raises(BatchValidationError, match=field if field not in ("K", "R", "t") else f"cameras.{field}"):
        validate_batch(batch)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda b: b.replace(cameras=None), "cameras: expected a jaxpose.camera.Cameras"),
        (lambda b: b.replace(keypoints2d=b.keypoints2d[:0], confidence=b.confidence[:0]), "at least 1 sample"),
        (lambda b: b.replace(keypoints2d=b.keypoints2d[:, :, :1]), "2 joints"),
        (lambda b: b.replace(pseudo3d_weight=b.pseudo3d_weight.at[1, 2].set(-0.5)), r"pseudo3d_weight: .* \[0, 1\]"),
    ],
)
def test_degenerate_batches(good, change, message):
    with pytest.raises(BatchValidationError, match=message):
        validate_batch(change(good))


# ----------------------------------------------------------------------------------------------
# Camera names across the tools (issue 34 items 17, 18; the rules: tests/formats/test_camera_names.py)


@pytest.mark.skipif(not paths.FORMATS.is_dir(), reason="needs ../shared/data/formats (real sample files)")
def test_pose2sim_scene_calibration_names_its_folders_cameras(tmp_path):
    """Pose2Sim's Calib_scene.toml names its cameras after the intrinsics image folders (int_cam01_img):
    they are the cameras of the folders cam01_json ... cam04_json, each with its own intrinsics."""
    root = tmp_path / "demo"
    shutil.copytree(paths.FORMATS / "openpose-json" / "pose2sim_demo_balancing_body25b", root / "balancing")
    scene = paths.FORMATS / "pose2sim-calib-toml" / "pose2sim_demo_Calib_scene.toml"
    shutil.copy(scene, root / "Calib_scene.toml")
    data = load_rig_project(RigProjectConfig(root=root, skeleton="body25b", validation_fraction=0.5), progress=False)
    assert data.camera_names == ("cam01", "cam02", "cam03", "cam04")
    rig = read_rig_calibration(scene)
    np.testing.assert_allclose(data.train.cameras_for(np.arange(1)).K[0], rig.cameras.K, rtol=1e-6)


# ----------------------------------------------------------------------------------------------
# Tracebacks where a sentence belongs (issue 34 items 10-12): each refusal is one line naming the
# culprit, raised while reading, and leaves every file as it was (the .jaxpose_cache aside).


def _broken_rig(defect: str) -> RigCalibration:
    rig = synthetic_rig(3)
    K, R, t = (np.array(field) for field in (rig.cameras.K, rig.cameras.R, rig.cameras.t))
    if defect == "coincident":
        R[2], t[2] = R[1], t[1]  # one camera's pose pasted onto another
    else:
        K[1, 0, 0] = K[1, 1, 1] = 1e-6  # near-singular: a focal length of a millionth of a pixel
    return dataclasses.replace(rig, cameras=rig.cameras.replace(K=K, R=R, t=t))


def _written(rig: RigCalibration, kind: str, folder) -> tuple:
    """`rig` written as `kind`: (the path to read, the field that holds camera 1's intrinsics)."""
    folder.mkdir()
    if kind == "anipose":
        (folder / "calibration.toml").write_text(aniposelib_style_toml(rig, scale=1000.0))
        return folder / "calibration.toml", r"table \[cam_1\], key 'matrix' \(camera 'cam1'\)"
    if kind == "easymocap":
        write_easymocap(folder, rig)
        return folder, r"intri\.yml: key 'K_cam1'"
    valid = dataclasses.replace(rig, cameras=rig.cameras.replace(K=synthetic_rig(3).cameras.K))
    save_cameras(folder / "cameras.json", {"rig": (list(rig.camera_names), valid.cameras)})
    document = json.loads((folder / "cameras.json").read_text())
    document["subjects"]["rig"][1]["K"] = np.asarray(rig.cameras.K[1]).tolist()  # what save_cameras refuses to write
    (folder / "cameras.json").write_text(json.dumps(document))
    return folder / "cameras.json", r"cameras\.json: subject 'rig', camera 1 \('cam1'\), field 'K'"


@pytest.mark.parametrize("kind", ["anipose", "easymocap", "camera file"])
def test_two_cameras_at_one_centre_are_named_by_every_calibration_reader(tmp_path, kind):
    path, _ = _written(_broken_rig("coincident"), kind, tmp_path / "calibration")
    expected = r"expected cameras at distinct centres.*cameras 'cam1' and 'cam2' at one centre"
    with pytest.raises(DataFormatError, match=expected):
        read_rig_calibration(path)


@pytest.mark.parametrize("kind", ["anipose", "easymocap", "camera file"])
def test_near_singular_intrinsics_are_named_by_every_calibration_reader(tmp_path, kind):
    path, field = _written(_broken_rig("singular"), kind, tmp_path / "calibration")
    with pytest.raises(DataFormatError, match=rf"{field}: expected intrinsics in pixels.*found fx 1e-06, fy 1e-06"):
        read_rig_calibration(path)


@pytest.mark.parametrize(
    "K, found",
    [
        ([[1500.0, 0, 960], [0, 15.0, 540], [0, 0, 1]], "fy 15"),  # fy / fx = 0.01
        ([[2e6, 0, 960], [0, 2e6, 540], [0, 0, 1]], r"fx 2e\+06"),
        ([[1.0, 0, 4000], [0, 1.0, 4000], [0, 0, 1]], r"condition number 3\.2e\+07"),
    ],
)
def test_absurd_focal_lengths_are_refused(K, found):
    with pytest.raises(DataFormatError, match=rf"^calib\.toml, camera 'c': expected intrinsics in pixels.*{found}"):
        check_intrinsics(np.array(K), "calib.toml, camera 'c'")


def test_near_singular_intrinsics_given_to_predict_are_named(tmp_path):
    with pytest.raises(DataFormatError, match=r"^--intrinsics fx fy cx cy: expected intrinsics in pixels.*found fx 1e-09"):
        intrinsics.read_intrinsics(["1e-9", "1e-9", "960", "540"])
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps({"K": [[1000.0, 0, 960], [0, 1e-3, 540], [0, 0, 1]], "dist": None}))
    with pytest.raises(DataFormatError, match=rf"^--intrinsics {camera}, field 'K': expected intrinsics in pixels.*fy 0\.001"):
        intrinsics.read_intrinsics([str(camera)])
    camera.write_text(json.dumps({"K": [[1000.0, 0, 960], [0, 1000.0, 540]]}))
    with pytest.raises(DataFormatError, match=r"field 'K': expected a 3x3 intrinsic matrix of finite numbers"):
        intrinsics.read_intrinsics([str(camera)])


def _every_file(root) -> dict:
    return {
        os.path.relpath(os.path.join(folder, name), root): open(os.path.join(folder, name), "rb").read()
        for folder, folders, names in os.walk(root)
        if CACHE_DIR not in os.path.relpath(folder, root).split(os.sep)
        for name in names
    }


@pytest.fixture(scope="module")
def example_project(tmp_path_factory):
    config = ExampleProjectConfig(recordings=1, frames_per_recording=60)
    return write_rig_project(tmp_path_factory.mktemp("rig") / "project", config)


def _refused_by_the_rig_command(project, run_dir) -> str:
    """The first line of `experiments.rig`'s refusal of `project`, which must change no file and write no run."""
    before = _every_file(project)
    with pytest.raises(SystemExit) as stop:
        rig_experiment.main(["--data.root", str(project), "--run.run-dir", str(run_dir), "--run.no-progress"])
    assert _every_file(project) == before and not run_dir.exists()
    message = str(stop.value.code)
    assert message.startswith("error: ") and "Traceback" not in message
    return message.splitlines()[0]


def test_a_frame_file_name_that_is_not_utf8_is_named(example_project, tmp_path):
    project = tmp_path / "project"
    shutil.copytree(example_project, project)
    frames = project / "walking01" / "cam02_json"
    name = os.fsdecode(b"clip_\xe9t\xe9_000000000999_keypoints.json")  # Latin-1 bytes, as an old archive holds them
    shutil.copy(sorted(frames.iterdir())[0], frames / name)
    line = _refused_by_the_rig_command(project, tmp_path / "run")
    expected = r"cam02_json: expected frame file names in UTF-8 .*found the file 'clip_\\xe9t\\xe9_0+999_keypoints\.json'"
    assert re.search(expected, line), line


@pytest.mark.parametrize("defect", ["coincident", "singular"])
def test_a_calibration_refused_by_the_rig_command_names_its_cameras(example_project, tmp_path, defect):
    project = tmp_path / "project"
    shutil.copytree(example_project, project)
    tables = (project / "calibration.toml").read_text().split("\n\n")
    if defect == "coincident":  # cam03's table gets cam02's pose
        pose = [line for line in tables[1].splitlines() if line.startswith(("rotation", "translation"))]
        kept = [line for line in tables[2].splitlines() if not line.startswith(("rotation", "translation"))]
        tables[2] = "\n".join(kept + pose)
        expected = r"calibration\.toml: expected cameras at distinct centres.*cameras 'cam02' and 'cam03' at one centre"
    else:
        focal = r"matrix = \[ \[ [^,]+, 0\.0, ([^\]]+)\], \[ 0\.0, [^,]+,"  # fx and fy of cam02 made 1e-9 px
        tables[1] = re.sub(focal, r"matrix = [ [ 1e-9, 0.0, \1], [ 0.0, 1e-9,", tables[1])
        expected = r"calibration\.toml: table \[cam_1\], key 'matrix' \(camera 'cam02'\): expected intrinsics in pixels"
    (project / "calibration.toml").write_text("\n\n".join(tables))
    assert re.search(expected, _refused_by_the_rig_command(project, tmp_path / "run"))
