"""The Rendered viewport's progressive loop without a window (mpp_render/viewport.py): coarse
first, then refined up to the F12 render of the view; a change abandons the work under way;
what did not change is reused, counted by the precompute calls it saves."""
import dataclasses
import threading

import numpy as np
import pytest

from mpp_render import viewport
from mpp_render.render import render
from mpp_render.viewport import Progressive, Stage, stage_scene, stages

from test_cache import calls, scene  # noqa: F401 (calls: a fixture)

COARSE = int(round(16000 * viewport.COARSE_PATHS))   # the coarse stage's paths


def small_scene(**kw):
    desc = scene(**kw)
    desc.settings = dataclasses.replace(desc.settings, samples=4, multiple_paths=16000)
    return desc


@pytest.fixture
def loop():
    images = []
    p = Progressive(on_image=images.append)
    yield p, images
    p.close()


def test_stages_go_from_coarse_to_the_viewport_samples():
    got = stages(16)
    coarse = (viewport.COARSE_PATHS, viewport.COARSE_LATTICE)
    assert got[0] == Stage(viewport.COARSE_SCALE, 1, *coarse[:1], True, coarse[1], False)
    assert [(s.scale, s.samples, s.paths, s.any_camera, s.resolution, s.surface_cache)
            for s in got[1:]] == [(1, 1, *coarse[:1], False, coarse[1], False),
                                  (1, 4, 1.0, False, 1.0, True), (1, 16, 1.0, False, 1.0, True)]
    assert stages(1)[1:] == [Stage(1, 1, 1.0, False)]
    assert [s.samples for s in stages(6)[1:]] == [1, 4, 6]
    desc = small_scene()
    coarse = stage_scene(desc, got[0])
    assert (coarse.camera.width, coarse.camera.height) == (10, 8)   # ceil(40/4), ceil(30/4)
    assert coarse.camera.plane == desc.camera.plane
    assert coarse.settings.multiple_paths == COARSE and coarse.settings.samples == 1
    # the one-sample stages gather per sample; the others as the scene says
    assert not coarse.settings.surface_cache and stage_scene(desc, got[2]).settings.surface_cache
    assert coarse.settings.multiple_resolution == \
        int(round(desc.settings.multiple_resolution * viewport.COARSE_LATTICE))
    assert desc.camera.width == 40 and desc.settings.multiple_paths == 16000   # not modified


def test_coarse_first_then_refined_ending_on_the_f12_render(warm, calls, loop):
    p, images = loop
    desc = small_scene()
    gen = p.show(desc)
    last = p.wait(gen, timeout=120)
    assert last is not None and last.last and not p.busy
    assert [i.stage for i in images] == [0, 1, 2]
    assert [i.rgba.shape for i in images] == [(8, 10, 4), (30, 40, 4), (30, 40, 4)]
    assert all(i.generation == gen for i in images)
    assert images[0].seconds < images[-1].seconds
    # the coarse stage's precompute (COARSE_PATHS of the paths) serves the 1-sample stage
    # too; the last has the scene's paths
    assert calls.paths == [COARSE, 16000]
    np.testing.assert_array_equal(last.rgba, render(desc).passes["Combined"])
    # the coarse picture is the same scene: its mean is close to the final one's
    assert abs(images[0].rgba[..., :3].mean() / last.rgba[..., :3].mean() - 1) < 0.25


def test_a_change_abandons_the_work_under_way():
    started, release, seen = threading.Event(), threading.Event(), []

    def slow_render(desc, should_cancel, any_camera):
        if desc.settings.seed == 1:           # the first scene: hold it until the change came
            started.set()
            release.wait(10)
            seen.append(should_cancel())
            return render(desc, should_cancel=should_cancel)
        return render(desc, should_cancel=should_cancel, any_camera=any_camera)

    images = []
    p = Progressive(render_fn=slow_render, on_image=images.append)
    try:
        first = small_scene()
        first.settings = dataclasses.replace(first.settings, seed=1)
        g1 = p.show(first)
        assert started.wait(10)
        second = small_scene(power=400.0)
        g2 = p.show(second)
        release.set()
        assert p.wait(g1, timeout=5) is None          # superseded
        last = p.wait(g2, timeout=120)
        assert last is not None and last.last
    finally:
        p.close()
    assert seen == [True]                              # the old render was told to stop
    assert all(i.generation == g2 for i in images)     # and nothing of it was shown
    assert [i.stage for i in images] == [0, 1, 2]
    np.testing.assert_array_equal(last.rgba, render(second).passes["Combined"])


def test_a_moved_light_reuses_the_world_light(warm, calls, loop):
    p, _ = loop
    desc = small_scene()
    assert p.wait(p.show(desc), timeout=120) is not None
    before = len(calls)
    moved = small_scene()
    moved.lights[1] = dataclasses.replace(moved.lights[1], position=np.array([1.2, -0.6, 1.8]))
    last = p.wait(p.show(moved), timeout=120)
    assert last is not None
    # two precomputes again (coarse and refined paths), each of the lights alone: the
    # world light was taken from the cache
    assert calls.since(before) == [("lights", COARSE), ("lights", 16000)]
    assert "world" in last.stats["reused"]
    np.testing.assert_array_equal(last.rgba, render(moved).passes["Combined"])


def test_an_orbit_shows_the_coarse_picture_without_a_precompute(warm, calls, loop):
    p, images = loop
    desc = small_scene()
    assert p.wait(p.show(desc), timeout=120) is not None
    before, n_images = len(calls), len(images)
    orbit = small_scene(cam_pos=(0.4, -0.5, 3.9))
    gen = p.show(orbit)
    coarse = p.wait(gen, stage=0, timeout=120)
    assert coarse is not None and coarse.stats.get("stale_camera") is True
    last = p.wait(gen, timeout=120)
    assert last is not None and "stale_camera" not in last.stats
    # the coarse stage took the earlier position's precompute; the later ones their own
    assert calls.since(before) == [("all", COARSE), ("all", 16000)]
    assert images[n_images].generation == gen and images[n_images].stage == 0
    np.testing.assert_array_equal(last.rgba, render(orbit).passes["Combined"])


def test_a_failing_render_is_reported_and_the_loop_goes_on():
    def failing(desc, should_cancel, any_camera):
        if desc.settings.seed == 5:
            raise ValueError("bad scene")
        return render(desc, should_cancel=should_cancel, any_camera=any_camera)

    p = Progressive(render_fn=failing, stages_fn=lambda d: [Stage(4, 1)])
    try:
        bad = small_scene()
        bad.settings = dataclasses.replace(bad.settings, seed=5)
        assert p.wait(p.show(bad), timeout=30) is None
        assert p.errors == ["ValueError: bad scene"] and not p.busy
        good = p.wait(p.show(small_scene()), timeout=60)
        assert good is not None and good.rgba.shape == (8, 10, 4)
    finally:
        p.close()


def test_a_light_moved_after_an_orbit_takes_the_earlier_world_light_for_the_coarse_picture(
        warm, calls, loop):
    p, _ = loop
    assert p.wait(p.show(small_scene()), timeout=120) is not None
    before = len(calls)
    both = small_scene(cam_pos=(0.4, -0.5, 3.9))
    both.lights[1] = dataclasses.replace(both.lights[1], position=np.array([1.2, -0.6, 1.8]))
    gen = p.show(both)
    coarse = p.wait(gen, stage=0, timeout=120)
    assert coarse is not None and coarse.stats.get("stale_camera") is True
    last = p.wait(gen, timeout=120)
    # coarse: the lights alone (the world light of the earlier position); then this
    # position's world light for the same paths; the last stage: all of it
    assert calls.since(before) == [("lights", COARSE), ("world", COARSE), ("all", 16000)]
    assert "stale_camera" not in last.stats
    np.testing.assert_array_equal(last.rgba, render(both).passes["Combined"])
