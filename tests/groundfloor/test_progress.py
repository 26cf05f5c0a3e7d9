"""Progress bars only on a terminal, and only when the command line asks for them."""

from __future__ import annotations

import io

import pytest

from groundfloor import progress


class Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


@pytest.fixture
def enabled():
    progress.enable(True)
    yield
    progress.enable(False)


def test_no_bar_when_stderr_is_a_file(enabled, monkeypatch):
    log = io.StringIO()  # a log file or a pipe: not a terminal
    monkeypatch.setattr("sys.stderr", log)
    items = [1, 2, 3]
    assert progress.progress(items, desc="work") is items
    assert list(progress.progress(items, desc="work")) == items
    assert log.getvalue() == ""


def test_bar_on_a_terminal(enabled, monkeypatch):
    term = Terminal()
    monkeypatch.setattr("sys.stderr", term)
    assert list(progress.progress(range(3), desc="work")) == [0, 1, 2]
    assert "work" in term.getvalue()


def test_no_bar_when_not_enabled(monkeypatch):
    monkeypatch.setattr("sys.stderr", Terminal())
    progress.enable(False)
    items = [1]
    assert progress.progress(items, desc="work") is items
