"""The cache between renders (mpp_render/cache.py): content keys, the memory cap, and the
precompute reused exactly when its inputs did not change (images identical to cold renders)."""
import dataclasses

import numpy as np
import pytest

from mpp_render import cache, precompute as pre_mod
from mpp_render.media import prepare
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, Surface, World


class Calls(list):
    """The kinds ('all', 'lights', 'world') of the cold precompute.precompute calls, and in
    ``paths`` the multiple_paths each was called with."""

    def __init__(self):
        super().__init__()
        self.paths = []

    def clear(self):
        super().clear()
        self.paths.clear()

    def since(self, n):
        """(kind, multiple_paths) of the calls after the first ``n``."""
        return list(zip(self, self.paths))[n:]


@pytest.fixture
def calls(monkeypatch):
    """Counts the calls of precompute.precompute (the cold computation)."""
    seen = Calls()
    real = pre_mod.precompute

    def counting(media, lights, world, *a, **kw):
        lit = bool(np.any(np.asarray(world.color) > 0))
        seen.append("all" if lights and lit else "lights" if lights else "world")
        seen.paths.append(kw.get("multiple_paths"))
        return real(media, lights, world, *a, **kw)

    monkeypatch.setattr(pre_mod, "precompute", counting)
    return seen


def scene(world=(0.2, 0.25, 0.3), power=150.0, cam_pos=(0.0, -0.3, 4.0), multiple=True):
    n = 18
    x = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rng = np.random.default_rng(4)
    dens = (np.clip(1 - np.sqrt(X ** 2 + Y ** 2 + Z ** 2), 0, None) * (0.5 + rng.random((n,) * 3)))
    i2w = np.eye(4)
    i2w[:3, :3] *= 2.0 / n
    i2w[:3, 3] = -1 + 1.0 / n
    cloud = Medium("cloud", dens.astype(np.float32), i2w, np.full(3, 4.0), np.full(3, 0.4), 0.3)
    lights = [Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.3, 0.2, -0.93])),
              Light("POINT", "pt", np.full(3, float(power)), position=np.array([1.5, -1.0, 1.5]),
                    radius=0.1)]
    ground = Surface("ground", np.array([[-3, -3, -1.1], [3, -3, -1.1], [3, 3, -1.1], [-3, 3, -1.1]],
                                        float), np.array([[0, 1, 2], [0, 2, 3]]))
    cam = Camera("PERSP", np.eye(4), 40, 30, (-0.5, 0.5, -0.375, 0.375))
    cam.cam_to_world[:3, 3] = cam_pos
    return SceneDescription(cam, lights, [cloud], surfaces=[ground], world=World(np.array(world)),
                            settings=Settings(samples=4, multiple=multiple, ambient_directions=8))


def assert_same_image(a, b):
    assert a.passes.keys() == b.passes.keys()
    for k in a.passes:
        np.testing.assert_array_equal(a.passes[k], b.passes[k], err_msg=k)


# -- keys and the store ------------------------------------------------------------------------

def test_digest_follows_content_type_and_shape():
    a = np.arange(6, dtype=np.float32)
    assert cache.digest(a, 1.0, "x") == cache.digest(a.copy(), 1.0, "x")
    assert cache.digest(a) != cache.digest(a.reshape(2, 3))
    assert cache.digest(a) != cache.digest(a.astype(np.float64))
    b = a.copy()
    b[3] += 1e-6
    assert cache.digest(a) != cache.digest(b)
    assert cache.digest([1, 2]) != cache.digest([[1, 2]]) != cache.digest("12")
    light = Light("SUN", "sun", np.full(3, 2.0))
    assert cache.digest(light) == cache.digest(dataclasses.replace(light))
    assert cache.digest(light) != cache.digest(dataclasses.replace(light, angle=0.01))
    with pytest.raises(TypeError):
        cache.digest(object())


def test_store_keeps_the_cap_drops_the_oldest_and_clears():
    entry = 1000 + cache.ENTRY_BYTES
    c = cache.Cache(limit=3 * entry)
    kb = np.zeros(250, np.float32)  # 1000 bytes
    assert c.put("k", 1, kb) and c.put("k", 2, kb.copy()) and c.put("k", 3, kb.copy())
    assert c.get("k", 1) is kb  # 1 is now the most recently used
    assert c.put("k", 4, kb.copy())
    assert c.get("k", 2) is None and c.get("k", 1) is kb and c.get("k", 4) is not None
    assert c.bytes == 3 * entry and len(c) == 3
    assert not c.put("k", 5, np.zeros(1000, np.float32))  # larger than the cap: not kept
    assert c.get("k", 5) is None
    s = c.stats()
    assert s["hits"]["k"] == 3 and s["misses"]["k"] == 2 and s["entries"] == 3
    assert c.clear() == 3 * entry and len(c) == 0 and c.bytes == 0


def test_a_zero_cap_keeps_nothing(monkeypatch):
    monkeypatch.setenv(cache.LIMIT_ENV, "0")
    c = cache.Cache()
    assert not c.put("k", 1, np.zeros(4)) and c.get("k", 1) is None
    assert not c.put("k", 2, "a small value") and len(c) == 0


# -- the precompute ----------------------------------------------------------------------------

def prepared(desc):
    from mpp_render.surfaces import prepare_surfaces
    return [prepare(m) for m in desc.media], prepare_surfaces(desc.surfaces)


def assert_same_precompute(a, b):
    assert a.layout == b.layout
    for f, g in zip(a.fields, b.fields):
        np.testing.assert_array_equal(f, g)
    for ms, mc in zip(a.multiple, b.multiple):
        for x, y in zip(ms, mc):
            assert (x is None) == (y is None)
            if x is not None:
                assert x.stride == y.stride and x.h == y.h
                for lx, ly in zip(x.levels, y.levels):
                    np.testing.assert_array_equal(lx, ly)


@pytest.mark.parametrize("change", ["nothing", "camera", "camera_single", "light"])
def test_cached_precompute_equals_the_cold_one(warm, change):
    """Each way of reuse (all kept; world light recomputed in place; light part recomputed
    with the world channels copied) gives exactly the fields of a cold precompute.  A moved
    camera keeps the light part only without multiple scattering: the light pyramids drift
    towards what the camera sees."""
    kw = dict(n_dirs=8, seed=3, threads=2, multiple=change != "camera_single")
    first = scene()
    media, surf = prepared(first)
    cache.precompute_cached(media, first.lights, first.world, first.camera, surfaces=surf, **kw)
    moved = scene(cam_pos=(0.5, -0.2, 3.5))
    second = {"nothing": scene(), "camera": moved, "camera_single": moved,
              "light": scene(power=400.0)}[change]
    media, surf = prepared(second)
    got = cache.precompute_cached(media, second.lights, second.world, second.camera,
                                  surfaces=surf, **kw)
    assert got.stats["reused"] == {"nothing": ["lights", "world"], "camera": [],
                                   "camera_single": ["lights"], "light": ["world"]}[change]
    cold = pre_mod.precompute(media, second.lights, second.world, second.camera, surfaces=surf,
                              **kw)
    assert_same_precompute(got, cold)


def test_second_render_reuses_the_precompute_and_matches_a_cold_render(warm, calls):
    first = render(scene())
    assert calls == ["all"] and first.stats["reused"] == []
    second = render(scene())
    assert calls == ["all"]  # no new precompute call
    assert second.stats["reused"] == ["lights", "world"]
    assert_same_image(first, second)
    cache.clear()
    cold = render(scene())
    assert cold.stats["reused"] == []
    assert_same_image(cold, second)


def test_changed_light_power_recomputes_the_lights_only(warm, calls):
    render(scene())
    calls.clear()
    brighter = render(scene(power=300.0))
    assert calls == ["lights"] and brighter.stats["reused"] == ["world"]
    cache.clear()
    cold = render(scene(power=300.0))
    assert_same_image(cold, brighter)


def test_camera_moves_recompute_the_world_light_only(warm, calls):
    """Without multiple scattering; with it the light pyramids follow the camera too."""
    render(scene(multiple=False))
    calls.clear()
    moved = render(scene(cam_pos=(0.4, -0.3, 4.2), multiple=False))
    assert calls == ["world"] and moved.stats["reused"] == ["lights"]
    cache.clear()
    assert_same_image(render(scene(cam_pos=(0.4, -0.3, 4.2), multiple=False)), moved)


def test_camera_moves_recompute_the_light_pyramids(warm, calls):
    render(scene())
    calls.clear()
    moved = render(scene(cam_pos=(0.4, -0.3, 4.2)))
    assert calls == ["all"] and moved.stats["reused"] == []
    cache.clear()
    assert_same_image(render(scene(cam_pos=(0.4, -0.3, 4.2))), moved)


def test_rotating_the_camera_keeps_everything(warm, calls):
    render(scene())
    calls.clear()
    desc = scene()
    c, s = np.cos(0.1), np.sin(0.1)
    desc.camera.cam_to_world[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    turned = render(desc)
    assert calls == [] and turned.stats["reused"] == ["lights", "world"]


def test_black_world_ignores_the_camera(warm, calls):
    render(scene(world=(0, 0, 0), multiple=False))
    calls.clear()
    moved = render(scene(world=(0, 0, 0), cam_pos=(1.0, 0.0, 3.0), multiple=False))
    assert calls == [] and moved.stats["reused"] == ["lights"]


def test_changed_density_or_multiple_scattering_recomputes(warm, calls):
    render(scene())
    calls.clear()
    desc = scene()
    desc.media[0].density = desc.media[0].density * np.float32(1.01)
    render(desc)
    assert calls == ["all"]
    calls.clear()
    render(scene(multiple=False))
    assert calls == ["all"]


def test_a_cancelled_render_keeps_nothing(warm):
    stages = []

    def progress(fraction, message):
        stages.append(message)

    def esc():
        return any(m.startswith("World light") for m in stages)

    out = render(scene(), progress=progress, should_cancel=esc)
    assert out.cancelled and len(cache.CACHE) == 0


@pytest.mark.parametrize("change", ["world", "light"])
def test_the_grounds_sky_deficit_follows_the_world_colour(warm, change):
    """With traced paths, a ground and a lit sky, the ground's share of the sky's deficit
    (skydeficit.sky_deficit's ``ground``) takes as many paths as weigh what the lights'
    paths weigh, so the lights' part is keyed by the sky's colour: another world colour
    recomputes both parts, and a changed light, whose world channels are copied from the
    cache, equals a cold precompute.  The lights' own paths do not carry the sky's light."""
    kw = dict(n_dirs=8, seed=3, threads=2, multiple=True, multiple_paths=20_000,
              surface_bounce=True)
    first = scene()
    media, surf = prepared(first)
    cache.precompute_cached(media, first.lights, first.world, first.camera, surfaces=surf, **kw)
    second = scene(world=(0.4, 0.5, 0.6)) if change == "world" else scene(power=400.0)
    media, surf = prepared(second)
    got = cache.precompute_cached(media, second.lights, second.world, second.camera,
                                  surfaces=surf, **kw)
    assert got.stats["reused"] == ([] if change == "world" else ["world"])
    cold = pre_mod.precompute(media, second.lights, second.world, second.camera, surfaces=surf,
                              **kw)
    assert_same_precompute(got, cold)
    dark = pre_mod.precompute(media, second.lights, World(), second.camera, surfaces=surf,
                              **kw)
    np.testing.assert_array_equal(cold.multiple[0][0].levels[0], dark.multiple[0][0].levels[0])

def test_the_grounds_specular_layer_keys_the_precompute(warm, calls):
    """The share of the sky a surface reflects takes every layer of its BSDF (the sky's
    deficit, precompute/skydeficit.py): a ground whose specular layer changes, its diffuse
    colour the same, is a new precompute, not the kept one."""
    render(scene())
    calls.clear()
    glossy = scene()
    glossy.surfaces[0] = dataclasses.replace(glossy.surfaces[0], specular=0.04, roughness=0.3)
    out = render(glossy)
    assert calls == ["all"] and out.stats["reused"] == []
