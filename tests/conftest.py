"""Shared test setup: a private visibility cache per test session, and Hypothesis profiles."""

import os

import pytest
from hypothesis import settings

# Developers explore new random cases on every run; CI (CI=true) replays a fixed, derandomised set
# so that a landing never depends on luck. Failures found locally are kept in .hypothesis/.
settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("CAMPLACE_CACHE_DIR", str(tmp_path_factory.mktemp("camplace-cache")))
    yield
    mp.undo()


def pytest_terminal_summary(terminalreporter):
    """Print the reliability suite's counts and the user-path command times when they ran."""
    import sys

    e2e = sys.modules.get("tests.e2e.test_user_paths")
    if e2e is not None and e2e.TIMINGS:
        terminalreporter.write_sep("-", "user paths: whole-command times")
        for cmd, secs in e2e.TIMINGS.items():
            terminalreporter.write_line(f"{secs:7.1f} s  camplace {cmd}")
    mod = sys.modules.get("tests.reliability.counts")
    if mod is None or not any(mod.COUNTS.values()):
        return
    terminalreporter.write_sep("-", "reliability suite")
    terminalreporter.write_line(", ".join(f"{k}: {v:,}" for k, v in mod.COUNTS.items()))
