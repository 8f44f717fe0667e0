"""The command lines' persistent compilation cache (jaxpose.compilation_cache): where it goes, how to
move or disable it, a cache JAX was given left alone, the experiments' command lines turning it on, and no
cache without the size bound.  What a shared or full cache does: tests/test_hostile_inputs.py (issue 42)."""

import pathlib

import jax
import pytest
from python_process import run_python

from experiments import cli, synthetic
from jaxpose.training import runner
from jaxpose.compilation_cache import ENVIRONMENT, MIN_COMPILE_TIME_S, cache_folder


def test_the_folder_follows_the_variable_then_xdg_then_the_home():
    home = pathlib.Path.home()
    assert cache_folder({ENVIRONMENT: "off"}) is None
    assert cache_folder({ENVIRONMENT: " OFF "}) is None
    assert cache_folder({ENVIRONMENT: "/data/xla", "XDG_CACHE_HOME": "/x"}) == pathlib.Path("/data/xla")
    assert cache_folder({ENVIRONMENT: "~/xla"}) == home / "xla"
    assert cache_folder({"XDG_CACHE_HOME": "/x"}) == pathlib.Path("/x/jaxpose/xla")
    assert cache_folder({"XDG_CACHE_HOME": "relative"}) == home / ".cache" / "jaxpose" / "xla"
    assert cache_folder({}) == home / ".cache" / "jaxpose" / "xla"


CHOSEN = """
import jax
from jaxpose.compilation_cache import enable_compilation_cache
print(enable_compilation_cache(), jax.config.jax_persistent_cache_min_compile_time_secs)
"""


@pytest.mark.processes
def test_a_cache_jax_was_given_is_kept_and_an_unwritable_folder_is_one_warning(tmp_path):
    kept = run_python(CHOSEN, tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax"), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    assert kept.stdout.split() == [str(tmp_path / "jax"), "0.0"]
    (tmp_path / "file").write_text("")
    refused = run_python(CHOSEN, tmp_path, **{ENVIRONMENT: str(tmp_path / "file" / "xla")})
    assert refused.stdout.split() == ["None", "1.0"]
    assert f"no compilation cache: {tmp_path / 'file' / 'xla'} cannot be written" in refused.stderr


@pytest.fixture
def jax_cache_settings():
    """Puts JAX's cache settings back after a test that turned the cache on in this process (nothing is
    compiled in between, so JAX never opened the folder)."""
    names = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs", "jax_compilation_cache_max_size")
    before = {name: getattr(jax.config, name) for name in names}
    yield
    for name, value in before.items():
        jax.config.update(name, value)


def test_every_experiment_run_turns_it_on_in_the_folder_given_before_loading(tmp_path, monkeypatch, jax_cache_settings):
    jax.config.update("jax_compilation_cache_dir", None)  # as without JAX_COMPILATION_CACHE_DIR
    monkeypatch.setenv(ENVIRONMENT, str(tmp_path / "xla"))
    seen = {}

    def load(data):  # the first thing that may compile
        seen["folder"] = jax.config.jax_compilation_cache_dir
        seen["min_time"] = jax.config.jax_persistent_cache_min_compile_time_secs
        raise SystemExit("loaded")

    config = cli.parse(synthetic.EXPERIMENT, ["--preset", "tiny", "--run.run-dir", str(tmp_path / "run")], "test")
    with pytest.raises(SystemExit, match="loaded"):
        runner.run(config, load)
    assert seen == {"folder": str(tmp_path / "xla"), "min_time": MIN_COMPILE_TIME_S} and (tmp_path / "xla").is_dir()


def test_without_filelock_there_is_no_cache_rather_than_one_that_breaks_the_others(tmp_path, monkeypatch, caplog, jax_cache_settings):
    """JAX bounds the cache's size only with filelock; a process without the bound writes programs that make
    every write of the processes with it fail (test_hostile_inputs, issue 42 case 10), so it writes none."""
    from jaxpose import compilation_cache

    jax.config.update("jax_compilation_cache_dir", None)
    monkeypatch.setattr(compilation_cache, "filelock", None)
    assert compilation_cache.enable_compilation_cache({ENVIRONMENT: str(tmp_path / "xla")}) is None
    assert jax.config.jax_compilation_cache_dir is None and not (tmp_path / "xla").exists()
    assert "no compilation cache: JAX bounds its size only with the filelock package (pip install filelock)" in caplog.text
