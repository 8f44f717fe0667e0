"""A Python child process for the tests: `code` run in the repository on the CPU, with a home of its own
and no compilation cache but the one the test names (JAX's or jaxpose's variables in `environment`)."""

import os
import subprocess
import sys

import paths

from jaxpose.compilation_cache import ENVIRONMENT


def run_python(code: str, tmp_path, **environment) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE") and k != ENVIRONMENT}
    env |= {"JAX_PLATFORMS": "cpu", "HOME": str(tmp_path / "home")} | environment
    return subprocess.run([sys.executable, "-c", code], cwd=paths.REPO, env=env, capture_output=True, text=True, timeout=300)
