"""The jaxpose camera file and the conversion of Human3.6M's cameras.h5."""

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from fixtures_real_data import h36m_cameras, h36m_project, humaneva_cameras, opencv_project, write_h36m_cameras_h5
from jaxpose.camera import Cameras, project
from help_text import assert_every_flag_documented
from jaxpose.formats.camera_file import convert_h36m_cameras, load_cameras, load_image_sizes, main, save_cameras
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.h36m_cameras import H36M_IMAGE_SIZES, read_h36m_cameras

RNG = np.random.default_rng(7)
POINTS = np.stack([RNG.uniform(-900, 900, 40), RNG.uniform(-900, 900, 40), RNG.uniform(0, 1800, 40)], axis=-1)


def _document(cameras):
    return {"format": "jaxpose-cameras", "version": 1, "distortion_model": "opencv", "subjects": {"S1": cameras}}


def _write(path, document):
    path.write_text(json.dumps(document))
    return path


def test_load_matches_opencv_projection(tmp_path):
    cameras = humaneva_cameras(np.random.default_rng(0))
    path = _write(tmp_path / "cams.json", _document(cameras))
    names, loaded = load_cameras(path)["S1"]
    assert names == ["C1", "C2", "C3"]
    assert loaded.K.dtype == np.float32 and loaded.K.shape == (3, 3, 3) and loaded.dist.shape == (3, 5)
    for index, camera in enumerate(cameras):
        pixels = np.asarray(project(loaded[index], POINTS))
        np.testing.assert_allclose(pixels, opencv_project(camera, POINTS), atol=1e-3)
    assert load_image_sizes(path) == {"S1": [(640, 480)] * 3}


def test_save_load_round_trip_and_null_distortion(tmp_path):
    cameras = humaneva_cameras(np.random.default_rng(1))
    cameras[1]["dist"] = None
    del cameras[2]["image_size"]
    path = _write(tmp_path / "cams.json", _document(cameras))
    rigs = load_cameras(path)
    np.testing.assert_array_equal(rigs["S1"][1].dist[1], np.zeros(5))  # null -> no distortion
    save_cameras(tmp_path / "again.json", rigs, load_image_sizes(path))
    again = load_cameras(tmp_path / "again.json")
    for field in ("K", "R", "t", "dist"):
        np.testing.assert_array_equal(getattr(again["S1"][1], field), getattr(rigs["S1"][1], field))
    assert load_image_sizes(tmp_path / "again.json")["S1"] == [(640, 480), (640, 480), None]

    pinhole = {"S2": (["a", "b"], rigs["S1"][1][:2].without_distortion())}
    save_cameras(tmp_path / "pinhole.json", pinhole, comment="world frame: camera a")
    assert load_cameras(tmp_path / "pinhole.json")["S2"][1].dist is None
    assert json.loads((tmp_path / "pinhole.json").read_text())["comment"] == "world frame: camera a"


def test_convert_h36m_cameras_keeps_the_documented_projection(tmp_path):
    cameras = {"S1": h36m_cameras(np.random.default_rng(2)), "S11": h36m_cameras(np.random.default_rng(3))}
    write_h36m_cameras_h5(tmp_path / "cameras.h5", cameras)
    convert_h36m_cameras(tmp_path / "cameras.h5", tmp_path / "cameras.json")
    document = json.loads((tmp_path / "cameras.json").read_text())
    assert document["distortion_model"] == "h36m" and sorted(document["subjects"]) == ["S1", "S11"]
    for rigs in (load_cameras(tmp_path / "cameras.json"), read_h36m_cameras(tmp_path / "cameras.h5")):
        for subject, subject_cameras in cameras.items():
            names, loaded = rigs[subject]
            assert names == [c["name"] for c in subject_cameras]
            assert loaded.distortion_model == "h36m"
            for index, camera in enumerate(subject_cameras):
                pixels = np.asarray(project(loaded[index], POINTS))
                np.testing.assert_allclose(pixels, h36m_project(camera, POINTS), atol=1e-3)
    sizes = load_image_sizes(tmp_path / "cameras.json")["S1"]
    assert sizes == [H36M_IMAGE_SIZES[c["name"]] for c in cameras["S1"]]


def test_cli_convert_and_check(tmp_path, capsys):
    write_h36m_cameras_h5(tmp_path / "cameras.h5", {"S9": h36m_cameras(np.random.default_rng(4))})
    main(["convert", str(tmp_path / "cameras.h5"), str(tmp_path / "out.json")])
    assert "S9: 4 cameras" in capsys.readouterr().out
    main(["check", str(tmp_path / "out.json")])
    assert "distortion h36m" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="error: .*missing.json"):
        main(["check", str(tmp_path / "missing.json")])


@pytest.mark.parametrize("subcommand, arguments", [("convert", ["CAMERAS_H5", "OUT_JSON"]), ("check", ["CAMERAS_JSON"])])
@pytest.mark.processes
def test_cli_help_runs_as_a_module_and_documents_every_argument(subcommand, arguments):
    command = [sys.executable, "-m", "jaxpose.formats.camera_file", subcommand, "--help"]
    result = subprocess.run(command, capture_output=True, text=True, check=True)
    assert_every_flag_documented(result.stdout.split("positional arguments")[1], arguments)


def _camera(**changes):
    camera = humaneva_cameras(np.random.default_rng(5))[0]
    camera.update(changes)
    return camera


@pytest.mark.parametrize(
    "camera, field, expected",
    [
        (_camera(R=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "'R'", "rotation"),
        (_camera(R=[[-1, 0, 0], [0, 1, 0], [0, 0, 1]]), "'R'", "det R = \\+1"),
        (_camera(K=[[800, 0, 320], [0, 800, 240]]), "'K'", "3x3 finite numbers"),
        (_camera(K=[[-800, 0, 320], [0, 800, 240], [0, 0, 1]]), "'K'", "fx, fy > 0"),
        (_camera(t=[0, 0]), "'t'", "3 finite numbers"),
        (_camera(t=[0, "x", 1]), "'t'", "3 finite numbers"),
        (_camera(dist=[0.1, 0.2]), "'dist'", "5 finite numbers"),
        (_camera(image_size=[640]), "'image_size'", "width, height"),
    ],
)
def test_invalid_field_names_file_subject_camera_and_field(tmp_path, camera, field, expected):
    path = _write(tmp_path / "bad.json", _document([camera]))
    with pytest.raises(DataFormatError, match=expected) as error:
        load_cameras(path)
    message = str(error.value)
    for part in (str(path), "subject 'S1'", "camera 0 ('C1')", f"field {field}", "Getting the data"):
        assert part in message


@pytest.mark.parametrize(
    "document, expected",
    [
        ({"format": "something else"}, '"format": "jaxpose-cameras"'),
        ({"format": "jaxpose-cameras", "version": 2}, '"version": 1'),
        ({**_document([]), "distortion_model": "division"}, "distortion_model"),
        ({**_document([]), "subjects": {}}, "non-empty"),
        (_document([_camera(), _camera()]), "unique"),
        (_document([{"K": []}]), '"name"'),
        ({**_document([_camera()]), "comment": ["not", "text"]}, '"comment": a string'),
    ],
)
def test_invalid_documents(tmp_path, document, expected):
    with pytest.raises(DataFormatError, match=expected):
        load_cameras(_write(tmp_path / "bad.json", document))


def test_unreadable_files(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        load_cameras(tmp_path / "missing.json")
    (tmp_path / "broken.json").write_text('{"format": ')
    with pytest.raises(DataFormatError, match="invalid JSON"):
        load_cameras(tmp_path / "broken.json")
    (tmp_path / "empty.h5").write_bytes(b"")
    with pytest.raises(DataFormatError, match="empty.h5.*h5py cannot read.*Getting the data"):
        read_h36m_cameras(tmp_path / "empty.h5")


def test_malformed_cameras_h5(tmp_path):
    path = tmp_path / "cameras.h5"
    write_h36m_cameras_h5(path, {"S1": h36m_cameras(np.random.default_rng(6))})
    with h5py.File(path, "a") as file:
        del file["subject1/camera3/T"]
        file["subject1/camera3/T"] = np.zeros(2)
        del file["subject1/camera4/k"]
    with pytest.raises(DataFormatError, match=r"subject1/camera3/T: expected 3 finite numbers"):
        read_h36m_cameras(path)
    with h5py.File(path, "a") as file:
        del file["subject1/camera3/T"]
        file["subject1/camera3/T"] = np.zeros((3, 1))
    with pytest.raises(DataFormatError, match=r"subject1/camera4: expected .*a dataset 'k'; found only \['Name', 'R'"):
        read_h36m_cameras(path)


def test_save_rejects_what_load_would_reject(tmp_path):
    cameras = Cameras(K=np.eye(3)[None], R=2 * np.eye(3)[None], t=np.zeros((1, 3)))
    with pytest.raises(DataFormatError, match="rotation"):
        save_cameras(tmp_path / "x.json", {"S1": (["cam"], cameras)})
    assert not (tmp_path / "x.json").exists()
