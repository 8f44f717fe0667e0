"""User-named outputs (jaxpose.formats.outputs) and jaxpose's log lines (jaxpose.logs)."""

import os
import subprocess
import sys

import pytest

from jaxpose.formats.outputs import OutputError, atomic_output, check_output


def test_existing_output_is_refused_and_left_byte_identical(tmp_path):
    existing = tmp_path / "poses.json"
    existing.write_bytes(b"precious")
    with pytest.raises(OutputError, match=r"poses\.json: exists; pass --overwrite"):
        check_output(existing, overwrite=False)
    assert existing.read_bytes() == b"precious"
    assert check_output(existing, overwrite=True) == existing


def test_an_input_is_never_an_output_even_with_overwrite(tmp_path):
    source = tmp_path / "detections.json"
    source.write_text("[]")
    alias = tmp_path / "sub" / ".." / "detections.json"
    (tmp_path / "sub").mkdir()
    with pytest.raises(OutputError, match="input"):
        check_output(alias, overwrite=True, inputs=[source])
    assert source.read_text() == "[]"


def test_a_folder_is_not_an_output_file(tmp_path):
    with pytest.raises(OutputError, match="is a folder"):
        check_output(tmp_path, overwrite=True, flag="--output")


def test_missing_parent_folders_are_made(tmp_path):
    target = tmp_path / "a" / "b" / "poses.csv"
    assert check_output(target, overwrite=False) == target
    assert target.parent.is_dir() and not target.exists()


def test_atomic_output_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = tmp_path / "poses.npz"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_output(target) as temporary:
            assert temporary.suffix == ".npz" and temporary.parent == tmp_path
            temporary.write_bytes(b"half")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["poses.npz"]


def test_atomic_output_renames_into_place(tmp_path):
    target = tmp_path / "poses.npz"
    target.write_bytes(b"old")
    with atomic_output(target) as temporary:
        temporary.write_bytes(b"new")
        assert target.read_bytes() == b"old"
    assert target.read_bytes() == b"new"
    assert sorted(os.listdir(tmp_path)) == ["poses.npz"]


@pytest.mark.processes
def test_jaxpose_info_lines_reach_the_terminal_once_whatever_configured_the_root_logger():
    script = (
        "import logging; logging.basicConfig(level=logging.WARNING, format='ROOT %(message)s');"
        "from jaxpose.logs import show_logs; show_logs(); show_logs();"
        "logging.getLogger('jaxpose.rig').info('resumed from step 7');"
        "logging.getLogger('jaxpose.training.runner').info('report written');"
        "logging.getLogger('other').info('not ours')"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    lines = result.stderr.splitlines()
    assert sum("resumed from step 7" in line for line in lines) == 1
    assert sum("report written" in line for line in lines) == 1
    assert not any(line.startswith("ROOT") or "not ours" in line for line in lines)
