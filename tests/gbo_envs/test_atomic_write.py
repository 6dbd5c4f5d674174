"""``atomic_write``: the target is replaced whole or not at all, with its permissions and links kept."""

from __future__ import annotations

import os
import stat
import sys

import pytest

from gbo_envs.atomic_write import atomic_write


def test_writes_new_and_replaces_existing_files(tmp_path):
    path = tmp_path / "sub" / "out.txt"
    with atomic_write(path) as handle:
        handle.write("first ü")
    assert path.read_text(encoding="utf-8") == "first ü"
    with atomic_write(path, "wb") as handle:
        handle.write(b"\x00second")
    assert path.read_bytes() == b"\x00second"
    assert [p.name for p in path.parent.iterdir()] == ["out.txt"]  # no temporary file left


def test_an_error_while_writing_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "out.csv"
    path.write_text("old,complete\n")
    with pytest.raises(RuntimeError, match="disk full"):
        with atomic_write(path) as handle:
            handle.write("new,part")
            handle.flush()
            assert path.read_text() == "old,complete\n"  # the target is untouched while writing
            raise RuntimeError("disk full")
    assert path.read_text() == "old,complete\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permission bits and symbolic links")
def test_permissions_and_symbolic_links_are_kept(tmp_path):
    target = tmp_path / "data.csv"
    target.write_text("old\n")
    os.chmod(target, 0o640)
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    with atomic_write(link) as handle:
        handle.write("new\n")
    assert link.is_symlink() and target.read_text() == "new\n"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640


def test_bad_mode_and_a_folder_as_target(tmp_path):
    with pytest.raises(ValueError, match="mode: expected one of"):
        with atomic_write(tmp_path / "x", "a"):
            pass
    with pytest.raises(IsADirectoryError, match="is a folder"):
        with atomic_write(tmp_path):
            pass
