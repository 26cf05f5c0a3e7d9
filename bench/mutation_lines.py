"""pytest plugin of bench/mutation.py: which tests run which lines of one module (the clean run).

Loaded with ``-p _mutation_lines`` in the copy of the tree; ``MUTATION_TARGET`` names the module's
file (relative path), ``MUTATION_LINES_OUT`` the JSON written at the end: ``{key: [lines]}`` where
the key is a test's node id, a test file or class (lines run by a module- or class-scoped
fixture's setup) or ``"*"`` (lines run at import, during collection or by a session-scoped
fixture: a mutant there may change every test).
"""

import json
import os
import sys
import threading

import pytest

TARGET = os.environ["MUTATION_TARGET"]
OUT = os.environ["MUTATION_LINES_OUT"]
_key = ["*"]
_hits: dict[str, set[int]] = {}
_is_target: dict[str, bool] = {}


def _local(frame, event, arg):
    if event == "line":
        _hits.setdefault(_key[-1], set()).add(frame.f_lineno)
    return _local


def _global(frame, event, arg):
    name = frame.f_code.co_filename
    hit = _is_target.get(name)
    if hit is None:
        hit = _is_target[name] = name.replace(os.sep, "/").endswith("/" + TARGET)
    if not hit:
        return None
    _hits.setdefault(_key[-1], set()).add(frame.f_lineno)
    return _local


sys.settrace(_global)
threading.settrace(_global)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _key.append(item.nodeid)
    yield
    _key.pop()


@pytest.hookimpl(hookwrapper=True)
def pytest_fixture_setup(fixturedef, request):
    scope = fixturedef.scope
    if scope == "function":
        yield
        return
    _key.append(request.node.nodeid if scope in ("module", "class") else "*")
    yield
    _key.pop()


def pytest_sessionfinish(session, exitstatus):
    sys.settrace(None)
    with open(OUT, "w") as fh:
        json.dump({k: sorted(v) for k, v in _hits.items()}, fh)
