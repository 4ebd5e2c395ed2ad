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


# The default run (tools/dev.sh test) shares the files between two pytest-xdist workers, a file
# at a time, in the order collected (--dist loadfile --no-loadscope-reorder).  The files that
# take longest go first, so that neither worker is left with one of them after the other has
# run out of work.  Seconds a file in such a run on a 2-core machine (--durations=0,
# 2026-12-07): test_wide_suite 295, test_sanitizers 238, test_accuracy 147, test_kernels 138;
# the next, test_shader_graph_bpy, 94.  One process took 1022 s there.  xdist's own order
# (the files with the most tests first) took 777 s with the sanitizers running alone at the
# end; this order took 788 s with both workers ending together.  That is the same time here,
# but the run's end no longer waits on whichever long file happens to come last.
LONGEST_FIRST = ("tests/test_sanitizers.py",
                 "tests/blender/test_wide_suite.py",
                 "tests/blender/test_accuracy.py",
                 "tests/test_kernels.py")


def pytest_collection_modifyitems(session, config, items):
    """The files of ``LONGEST_FIRST`` first, in that order; the rest as collected."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(LONGEST_FIRST)))
