"""Shared test setup: a private visibility cache per test session."""

import pytest


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("CAMPLACE_CACHE_DIR", str(tmp_path_factory.mktemp("camplace-cache")))
    yield
    mp.undo()
