"""Every ```python block of README.md runs, in order, in one namespace (as a reader pastes them)."""

from __future__ import annotations

import re

import matplotlib
import pytest

from tests.support import REPO_ROOT

BLOCKS = re.findall(r"```python\n(.*?)```", (REPO_ROOT / "README.md").read_text(), re.S)


@pytest.mark.slow
def test_readme_python_blocks_run(monkeypatch, tmp_path):
    matplotlib.use("Agg")
    monkeypatch.chdir(tmp_path)  # anything a block writes stays out of the checkout
    assert len(BLOCKS) >= 4
    namespace = {"__name__": "__readme__"}
    for number, code in enumerate(BLOCKS, 1):
        exec(compile(code, f"README.md python block {number}", "exec"), namespace)
