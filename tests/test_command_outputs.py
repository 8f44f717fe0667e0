"""Every command that writes a user-named output refuses, before any work and in one line, an output that
exists (without --overwrite), that is a folder, or that is one of its own inputs (even with --overwrite),
and leaves every file that was there byte-identical (`jaxpose.formats.outputs`).

The run directory given to predict and export holds no checkpoint: a command that did any work before
checking its outputs would stop with the checkpoint's error instead of the output's.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fixtures_real_data import h36m_cameras, write_h36m_cameras_h5
from jaxpose import calibrate, export, predict
from jaxpose.formats import camera_file


def _workspace(root: Path) -> dict[str, Path]:
    """Inputs of every command (their content is never read: the refusals come first)."""
    files = {
        "detections": root / "detections.json",
        "npz": root / "detections.npz",
        "h5": root / "cameras.h5",
        "reference": root / "reference.json",
        "config": root / "run" / "config.json",  # a run directory's own file
    }
    for path in files.values():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(json.dumps({"file": path.name}).encode())
    files["run"] = root / "run"
    return files


# name -> (entry point, argv writing to an output path, argv writing over an input, an output file name)
Argv = Callable[[dict[str, Path], Path], list[str]]
COMMANDS: dict[str, tuple[Callable, Argv, Callable[[dict[str, Path]], list[str]] | None, str]] = {
    "predict --output": (
        predict.main,
        lambda w, out: ["--checkpoint", str(w["run"]), "--input", str(w["detections"]), "--output", str(out)],
        lambda w: ["--checkpoint", str(w["run"]), "--input", str(w["detections"]), "--output", str(w["detections"])],
        "poses.json",
    ),
    "predict --animation": (
        predict.main,
        lambda w, out: ["--checkpoint", str(w["run"]), "--input", str(w["detections"]),
                        "--output", str(w["run"].parent / "new.json"), "--animation", str(out)],
        None,  # an input is never a .gif or .mp4, the only suffixes --animation takes
        "clip.gif",
    ),
    "export": (
        export.main,
        lambda w, out: [str(w["run"]), "--output", str(out)],
        lambda w: [str(w["run"]), "--output", str(w["config"].with_suffix(".onnx"))],  # metadata over config.json
        "lifter.onnx",
    ),
    "calibrate": (
        calibrate.main,
        lambda w, out: ["--input", str(w["npz"]), "--output", str(out)],
        lambda w: ["--input", str(w["npz"]), "--reference", str(w["reference"]), "--output", str(w["reference"])],
        "cameras.json",
    ),
    "camera_file convert": (
        camera_file.main,
        lambda w, out: ["convert", str(w["h5"]), str(out)],
        lambda w: ["convert", str(w["h5"]), str(w["h5"])],
        "cameras.json",
    ),
}


def _snapshot(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): None if p.is_dir() else p.read_bytes() for p in sorted(root.rglob("*"))}


def _refusal(main: Callable, argv: list[str]) -> str:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    message = str(stop.value.code)
    assert "\n" not in message and "Traceback" not in message
    return message


@pytest.mark.parametrize("command", COMMANDS)
def test_an_existing_output_is_refused_and_every_file_left_as_it_was(command, tmp_path):
    main, argv, _, name = COMMANDS[command]
    workspace = _workspace(tmp_path)
    output = tmp_path / name
    output.write_bytes(b"an earlier result")
    before = _snapshot(tmp_path)
    message = _refusal(main, argv(workspace, output))
    assert f"{output}: exists; pass --overwrite to replace it" in message
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("command", [name for name, case in COMMANDS.items() if case[2] is not None])
def test_an_input_is_never_an_output_even_with_overwrite(command, tmp_path):
    main, _, argv, _ = COMMANDS[command]
    workspace = _workspace(tmp_path)
    before = _snapshot(tmp_path)
    message = _refusal(main, [*argv(workspace), "--overwrite"])
    # Over an input file, or (export's case: config.onnx's metadata over config.json) inside the input run folder.
    assert ("is this command's input" in message and "would destroy it" in message) or "is inside this command's input folder" in message
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("command", COMMANDS)
def test_a_folder_is_not_an_output(command, tmp_path):
    main, argv, _, name = COMMANDS[command]
    workspace = _workspace(tmp_path)
    folder = tmp_path / name
    folder.mkdir()
    (folder / "kept.txt").write_text("mine")
    before = _snapshot(tmp_path)
    message = _refusal(main, [*argv(workspace, folder), "--overwrite"])
    assert f"{folder}: is a folder" in message
    assert _snapshot(tmp_path) == before


def test_the_siblings_of_an_output_are_checked_too(tmp_path):
    """export writes lifter.json and lifter.jax_export beside lifter.onnx, calibrate cameras.md and
    cameras.png beside cameras.json: an existing one stops the command as the named output does."""
    workspace = _workspace(tmp_path)
    (tmp_path / "lifter.jax_export").write_bytes(b"earlier")
    (tmp_path / "cameras.png").write_bytes(b"earlier")
    before = _snapshot(tmp_path)
    assert "lifter.jax_export: exists" in _refusal(export.main, COMMANDS["export"][1](workspace, tmp_path / "lifter.onnx"))
    message = _refusal(calibrate.main, COMMANDS["calibrate"][1](workspace, tmp_path / "cameras.json"))
    assert "cameras.png: exists" in message
    assert _snapshot(tmp_path) == before


def test_predict_plot_folder_of_earlier_figures_and_a_plot_file_are_refused(tmp_path):
    workspace = _workspace(tmp_path)
    (tmp_path / "plots").mkdir()
    (tmp_path / "plots" / "lifting_00003.png").write_bytes(b"earlier")
    (tmp_path / "plot.png").write_bytes(b"a file")
    before = _snapshot(tmp_path)
    common = COMMANDS["predict --output"][1](workspace, tmp_path / "poses.json")
    message = _refusal(predict.main, [*common, "--plot", str(tmp_path / "plots")])
    assert "holds 1 figures lifting_*.png already (lifting_00003.png, ...); pass --overwrite" in message
    message = _refusal(predict.main, [*common, "--plot", str(tmp_path / "plot.png"), "--overwrite"])
    assert "is a file; give a folder" in message
    assert _snapshot(tmp_path) == before


def test_convert_replaces_its_output_with_overwrite_and_leaves_no_temporary_file(tmp_path):
    write_h36m_cameras_h5(tmp_path / "cameras.h5", {"S9": h36m_cameras(np.random.default_rng(4))})
    output = tmp_path / "cameras.json"
    output.write_text("an earlier result")
    camera_file.main(["convert", str(tmp_path / "cameras.h5"), str(output), "--overwrite"])
    assert list(camera_file.load_cameras(output)) == ["S9"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cameras.h5", "cameras.json"]


def test_predict_trc_person_files_of_an_earlier_run_are_refused(tmp_path):
    """A .trc output may write <stem>.person<P>[.seg<S>].trc beside FILE: an existing one stops the command too."""
    workspace = _workspace(tmp_path)
    (tmp_path / "poses.person1.seg2.trc").write_bytes(b"earlier")
    (tmp_path / "poses.other.trc").write_bytes(b"not ours")
    before = _snapshot(tmp_path)
    message = _refusal(predict.main, COMMANDS["predict --output"][1](workspace, tmp_path / "poses.trc"))
    assert "poses.person1.seg2.trc: exists; pass --overwrite" in message
    assert _snapshot(tmp_path) == before
