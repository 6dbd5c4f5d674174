"""evaluation.allocator: glibc keeps the fits' freed memory, and the gbo command sets it."""

from __future__ import annotations

import platform

import pytest

import evaluation.allocator as allocator
from evaluation.cli import main as gbo


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_glibc_takes_every_setting():
    assert allocator.retain_freed_memory() is True


def test_off_glibc_nothing_is_changed(monkeypatch):
    monkeypatch.setattr(allocator.platform, "libc_ver", lambda: ("musl", "1.2"))
    assert allocator.retain_freed_memory() is False


def test_the_gbo_command_applies_it(monkeypatch, capsys):
    calls = []
    monkeypatch.setattr(allocator, "retain_freed_memory", lambda: calls.append(1) or True)
    assert gbo(["sessions", "--db", "/nonexistent/runs.sqlite"]) in (0, 1, 2)
    assert calls == [1]
