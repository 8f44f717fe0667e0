"""MPI-INF-3DHP test-set loading from annot_data.mat fixtures of both MATLAB kinds."""

import shutil

import h5py
import numpy as np
import pytest
import scipy.io

from fixtures_real_data import MPI_FILE_INDEX_OF_OURS, write_mpi_inf_3dhp_test_set
from jaxpose.formats.errors import DataFormatError
from jaxpose.datasets.mpi_inf_3dhp import ACTIVITY_NAMES, camera_intrinsics, load_mpi_inf_3dhp_test
from jaxpose.skeleton import MPI_INF_3DHP_17


@pytest.fixture(scope="module")
def mpi_files(tmp_path_factory):
    """TS1 as a v7.3 (HDF5) file, TS5 in the older MATLAB format; annot2 made through our K."""
    K = {name: camera_intrinsics(name) for name in ("TS1", "TS5")}
    return write_mpi_inf_3dhp_test_set(tmp_path_factory.mktemp("3dhp"), {"TS1": "v7.3", "TS5": "v5"}, K=K)


def test_fixture_kinds_are_what_they_claim(mpi_files):
    assert h5py.is_hdf5(mpi_files.root / "TS1" / "annot_data.mat")
    assert not h5py.is_hdf5(mpi_files.root / "TS5" / "annot_data.mat")


def test_valid_frames_joint_order_units_and_labels(mpi_files):
    data = load_mpi_inf_3dhp_test(mpi_files.root, sequences=("TS1", "TS5"), progress=False)
    assert data.skeleton == MPI_INF_3DHP_17
    valid = {name: np.flatnonzero(mpi_files.valid[name]) for name in ("TS1", "TS5")}
    assert len(data) == sum(len(v) for v in valid.values())
    assert data.keypoints2d.shape == (len(data), 17, 2) and data.univ3d.shape == (len(data), 17, 3)
    assert data.keypoints2d.dtype == data.univ3d.dtype == np.float32
    for name in ("TS1", "TS5"):
        rows = data.sequence == name
        frames = valid[name]
        np.testing.assert_array_equal(data.frame[rows], frames)
        order = list(MPI_FILE_INDEX_OF_OURS)
        np.testing.assert_allclose(data.keypoints2d[rows], mpi_files.annot2[name][frames][:, order], atol=1e-3)
        np.testing.assert_allclose(data.camera3d[rows], mpi_files.annot3[name][frames][:, order], atol=1e-3)
        univ = mpi_files.univ_annot3[name][frames][:, order]
        np.testing.assert_allclose(data.univ3d[rows], univ - univ[:, :1], atol=1e-3)  # root-relative, mm
        np.testing.assert_array_equal(data.activity[rows], mpi_files.activity[name][frames])
        names = [ACTIVITY_NAMES[code] for code in mpi_files.activity[name][frames]]
        np.testing.assert_array_equal(data.activity_name[rows], names)
        # annot2 is the projection of annot3 through the K we document for this sequence.
        projected = np.einsum("nij,nkj->nki", data.K[rows], data.camera3d[rows])
        np.testing.assert_allclose(projected[..., :2] / projected[..., 2:], data.keypoints2d[rows], atol=1e-3)
    np.testing.assert_array_equal(data.univ3d[:, 0], 0.0)
    assert MPI_INF_3DHP_17.joint_names[0] == "Pelvis"


def test_intrinsics_from_the_published_camera_parameters():
    np.testing.assert_allclose(
        camera_intrinsics("TS2"), [[1500.1723, 0, 1017.3873], [0, 1500.8324, 1043.0320], [0, 0, 1]], atol=1e-3
    )
    np.testing.assert_allclose(
        camera_intrinsics("TS6"), [[1683.9835, 0, 939.8575], [0, 1672.5937, 560.1407], [0, 0, 1]], atol=1e-3
    )
    assert len(ACTIVITY_NAMES) == 7


def test_errors(mpi_files, tmp_path):
    def expect(match, root, sequences=("TS1", "TS5")):
        with pytest.raises(DataFormatError, match=match) as error:
            load_mpi_inf_3dhp_test(root, sequences=sequences, progress=False)
        assert "Getting the data" in str(error.value)

    expect(r"TS2/annot_data.mat: expected MPI-INF-3DHP test annotations; found no such file", mpi_files.root, ("TS2",))
    root = tmp_path / "copy"
    shutil.copytree(mpi_files.root, root)
    v73 = root / "TS1" / "annot_data.mat"
    v73.write_bytes(v73.read_bytes()[:3000])
    expect(r"TS1/annot_data.mat: expected MPI-INF-3DHP test annotations \(an HDF5 file\)", root)
    v5 = root / "TS5" / "annot_data.mat"
    v5.write_bytes(v5.read_bytes()[:300])
    expect(r"TS5/annot_data.mat: expected MPI-INF-3DHP test annotations \(a MATLAB .mat file\)", root, ("TS5",))
    v5.write_bytes(b"")
    expect(r"TS5/annot_data.mat: expected .*a MATLAB .mat file", root, ("TS5",))
    shutil.copy(mpi_files.root / "TS1" / "annot_data.mat", v73)
    with h5py.File(v73, "a") as file:
        del file["univ_annot3"]
    expect(r"expected MPI-INF-3DHP test annotations: a dataset 'univ_annot3'", root, ("TS1",))
    with h5py.File(v73, "a") as file:
        file["univ_annot3"] = np.zeros((len(mpi_files.valid["TS1"]), 1, 16, 3))
    match = r"TS1/annot_data.mat univ_annot3: expected a 3 x 17 x 1 x \d+ array; found shape \(3, 16, 1, \d+\)"
    expect(match, root, ("TS1",))
    variables = scipy.io.loadmat(mpi_files.root / "TS5" / "annot_data.mat")
    scipy.io.savemat(v5, {k: v for k, v in variables.items() if not k.startswith("__") and k != "activity_annotation"})
    expect(r"variables .*; found \['activity_annotation'\] missing", root, ("TS5",))


def test_unknown_sequence_name(mpi_files):
    with pytest.raises(ValueError, match="TS7"):
        load_mpi_inf_3dhp_test(mpi_files.root, sequences=("TS7",))
