"""Settings shared by every test.

The renderer keeps precompute results and grids between renders (``mpp_render.cache``).  The
tests were written for cold renders (a second render of a scene must run, and check, the
whole pipeline again), so the cache is switched off (``MPP_CACHE_MB=0``, inherited by the
subprocesses the tests start) and emptied around every test; the tests of the cache turn it
back on themselves (tests/test_cache.py, tests/blender/test_animation.py)."""
import pytest

from mpp_render import cache


@pytest.fixture(autouse=True)
def cold_cache(monkeypatch):
    monkeypatch.setenv(cache.LIMIT_ENV, "0")
    cache.clear()
    yield
    cache.clear()


@pytest.fixture
def warm(monkeypatch):
    """The cache switched on (256 MB) for the tests of reuse; yields the store."""
    monkeypatch.setenv(cache.LIMIT_ENV, "256")
    cache.clear()
    yield cache.CACHE
    cache.clear()
