"""The compiled kernels are cached on disk, also when the package folder is read-only.

A copy of the ``gbo_envs`` package in a read-only folder (a read-only bind mount when the tests
run as root, whom file modes do not stop; else file modes) is imported by two fresh processes
with their own home folder: the first compiles the open-loop kernel and numba writes it to its
per-user cache (``~/.cache/numba``), the second loads it from there without compiling.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import gbo_envs

PROBE = """
import json
from gbo_envs.physics import kernels
kernels.warm_up(("open_loop",))
fn = kernels.open_loop_kernel
print(json.dumps([len(fn.stats.cache_hits), len(fn.stats.cache_misses), str(fn._cache._cache_path)]))
"""


def _read_only_runner(folder: Path):
    """A function running a command in ``folder``, made read-only, or None where this cannot be arranged."""
    if os.geteuid() != 0:
        for path in folder.rglob("*"):
            path.chmod(0o555 if path.is_dir() else 0o444)
        folder.chmod(0o555)
        return lambda command, env: subprocess.run(command, env=env, capture_output=True, text=True, cwd=folder)
    unshare = shutil.which("unshare")
    if unshare is None:
        return None
    mount = f"mount --bind {folder} {folder} && mount -o remount,bind,ro {folder}"
    probe = subprocess.run([unshare, "-m", "--propagation", "private", "sh", "-c", f"{mount} && ! touch {folder}/x"],
                           capture_output=True)
    if probe.returncode != 0:
        return None

    def run(command, env):
        line = " ".join(f"'{part}'" for part in command)
        return subprocess.run([unshare, "-m", "--propagation", "private", "sh", "-c", f"{mount} && {line}"],
                              env=env, capture_output=True, text=True, cwd=folder)

    return run


@pytest.mark.slow
def test_a_read_only_package_caches_its_kernels_per_user(tmp_path):
    package = Path(gbo_envs.__file__).parent
    tree = tmp_path / "tree"
    shutil.copytree(package, tree / "gbo_envs", ignore=shutil.ignore_patterns("__pycache__"))
    home = tmp_path / "home"
    home.mkdir()
    run = _read_only_runner(tree)
    if run is None:
        pytest.skip("cannot make a folder read-only here (root without mount namespaces)")
    env = {key: value for key, value in os.environ.items() if not key.startswith(("NUMBA_", "XDG_"))}
    env.update(HOME=str(home), PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
    outputs = []
    for _ in range(2):
        done = run([sys.executable, "-c", PROBE], env)
        assert done.returncode == 0, done.stderr
        outputs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    first, second = outputs
    assert first[:2] == [0, 1]  # compiled
    assert second[:2] == [1, 0]  # loaded from the cache, not compiled
    assert Path(first[2]).is_relative_to(home / ".cache" / "numba")
    assert not list((tree / "gbo_envs").rglob("*.nbi"))  # nothing written into the package
