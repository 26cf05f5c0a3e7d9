"""Shared, session-scoped fixtures: small simulated campaigns, made once per test session.

Keep them small: the whole suite must run in a few minutes on 2 cores. A test that needs a
special campaign (an effect, another seed) simulates its own, as short as it can.

No test skips for a missing dependency: what a test needs is installed by ``make test`` (evo,
Chromium) or is there in CI (``../shared/``), and a missing one fails the test with a message
saying what to do. With ``SINDY_EKF_NO_SKIPS=1`` (set by ``make test``) a skipped test anyway
fails the session, so that a skip added later cannot hide a test.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.support import SHARED


#: modules holding the suite's longest tests, longest first (over a minute each in ``pytest --durations`` on
#: 2 cores, 2026-11-29): collected first and in this order, so that pytest-xdist (``--dist loadfile
#: --no-loadscope-reorder``, make test) hands them out at the start and no worker is left running one of
#: them at the end while the other waits
LONG_MODULES = ("test_inject_real.py", "test_scaleout.py", "test_real_warthog.py", "test_simulate_cli.py",
                "test_gain_profile.py", "test_report.py", "test_field_bags.py", "test_search.py")


def pytest_collection_modifyitems(config, items):
    """Put the tests of :data:`LONG_MODULES` first, in its order (a stable sort: every other order is kept)."""
    rank = {name: i for i, name in enumerate(LONG_MODULES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONG_MODULES)))


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The sibling ``shared/`` folder (data contract, thesis, real campaigns)."""
    if not SHARED.is_dir():
        pytest.fail(f"{SHARED} is missing: this test reads the thesis text or the real Warthog data "
                    "of the project's shared/ folder, which must sit beside the checkout (CI has it; "
                    "in a clone elsewhere, link it: ln -s /path/to/shared ../shared)", pytrace=False)
    return SHARED


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """With ``SINDY_EKF_NO_SKIPS=1``, name the skipped tests (``pytest_sessionfinish`` fails the run)."""
    skipped = terminalreporter.stats.get("skipped", [])
    if os.environ.get("SINDY_EKF_NO_SKIPS") == "1" and skipped:
        terminalreporter.write_line(f"SINDY_EKF_NO_SKIPS=1: {len(skipped)} test(s) skipped, which make test "
                                    "does not allow (install what they need instead):", red=True)
        for report in skipped:
            terminalreporter.write_line(f"  {report.nodeid}: {report.longrepr[-1] if report.longrepr else ''}")


def pytest_sessionfinish(session, exitstatus):
    """With ``SINDY_EKF_NO_SKIPS=1``, a session with a skipped test exits non-zero."""
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if (os.environ.get("SINDY_EKF_NO_SKIPS") == "1" and reporter is not None
            and reporter.stats.get("skipped") and exitstatus == 0):
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


@pytest.fixture(scope="session")
def small_campaign(tmp_path_factory) -> Path:
    """A small simulated tracker campaign (seed 1, about 4 minutes of driving, 9 runs)."""
    from simulation.campaign import simulate_campaign

    out = tmp_path_factory.mktemp("campaign") / "small"
    simulate_campaign(out, seed=1, minutes=4.0)
    return out


@pytest.fixture(scope="session")
def small_trajectory(small_campaign, tmp_path_factory) -> Path:
    """``small_campaign`` preprocessed into a trajectory campaign (preprocess --out)."""
    from identification.preprocessing.preprocess import preprocess_campaign

    out = tmp_path_factory.mktemp("trajectory") / "small"
    preprocess_campaign(small_campaign, out)
    return out


# A campaign as independently generated tracker campaigns are recorded (issue 14): every message
# its own 2-12 ms receive latency, so spurious AT960 pulses next to real ones are stored out of
# stamp order (seed 4: in five runs), plus two tracker clock resets, one half-way through run_06
# (two parts of ~19 s) and one 15 % into run_09 (a part too short to keep).
FIELD_SEED, FIELD_MINUTES = 4, 4.0
FIELD_RESETS = {"run_06": ("at960", 0.5), "run_09": ("ltd800", 0.15)}


@pytest.fixture(scope="session")
def field_campaign(tmp_path_factory) -> Path:
    """The campaign of issue 14: receive jitter and two clock resets (see FIELD_RESETS)."""
    from simulation.campaign import simulate_campaign

    out = tmp_path_factory.mktemp("field") / "jitter"
    simulate_campaign(out, seed=FIELD_SEED, minutes=FIELD_MINUTES, receive_jitter_s=True,
                      clock_resets=FIELD_RESETS)
    return out


@pytest.fixture(scope="session")
def field_twin(tmp_path_factory) -> Path:
    """``field_campaign`` without the receive jitter: every topic stored in stamp order."""
    from simulation.campaign import simulate_campaign

    out = tmp_path_factory.mktemp("field") / "twin"
    simulate_campaign(out, seed=FIELD_SEED, minutes=FIELD_MINUTES, clock_resets=FIELD_RESETS)
    return out
