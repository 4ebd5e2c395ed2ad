"""Esc: ``should_cancel`` stops a render within 0.5 s in every stage (light attenuation, world
light, light pyramids, the march at a few samples per pixel), the precompute's memory is
released, and the next render is complete and bit-identical to one never interrupted.

The scene is a noisy 96^3 cloud under a sun, a point light and a grey sky with multiple
scattering, so the precompute takes a few seconds on two threads (40 000 light paths per light:
every stage is there, at a sixth of the default's paths, which would take half a minute)."""
import gc
import threading
import time
import tracemalloc

import numpy as np
import pytest

from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World

N = 96
LATENCY_S = 0.5


def cloud(n=N):
    x = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rng = np.random.default_rng(5)
    d = np.clip(1 - np.sqrt(X ** 2 + Y ** 2 + Z ** 2), 0, None) * (0.6 + 0.4 * rng.random((n,) * 3))
    i2w = np.eye(4)
    i2w[:3, :3] *= 2.0 / n
    i2w[:3, 3] = -1 + 1.0 / n
    return Medium("cloud", d.astype(np.float32), i2w, np.full(3, 4.0), np.full(3, 0.4), 0.3)


def big_scene(n=N, width=80, height=64, samples=1):
    """The cloud filling the middle of the frame; the defaults make the precompute the slow
    part, ``march_scene`` the march."""
    cam = Camera("PERSP", np.eye(4), width, height, (-0.3, 0.3, -0.24, 0.24))
    cam.cam_to_world[:3, 3] = [0, 0, 5]
    lights = [Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.3, 0.2, -0.93])),
              Light("POINT", "pt", np.full(3, 300.0), position=np.array([2.0, 1.0, 2.0]))]
    return SceneDescription(cam, lights, [cloud(n)], world=World(np.full(3, 0.1)),
                            settings=Settings(samples=samples, threads=2, multiple=True,
                                              multiple_paths=40000))


def march_scene():
    """A quick precompute (48^3) and a march of a second or more (640 x 512 pixels, 1 sample,
    80 tiles of 64 x 64 pixels, each a few hundredths of a second), so that Esc 0.1 s into the
    march finds most tiles unwritten on any machine (at 320 x 256 an idle machine, the cloud
    stepping a voxel at a time, had marched all 20 first).  Esc waits for the tiles being
    marched, so at many samples per pixel it waits longer, see docs/robustness.md."""
    return big_scene(48, 640, 512, 1)


class Esc:
    """``should_cancel`` that turns true ``delay`` s after the start, or ``delay`` s after
    the first progress message starting with ``stage``.  ``flipped`` is the moment it turned
    true (Esc pressed), whether or not the render has asked yet."""

    def __init__(self, delay, stage=None):
        self.delay, self.stage = delay, stage
        self.t0 = time.perf_counter() if stage is None else None
        self.stages = []
        self.polled_after = 0

    @property
    def flipped(self):
        return None if self.t0 is None else self.t0 + self.delay

    def progress(self, fraction, message):
        self.stages.append(message)
        if self.t0 is None and message.startswith(self.stage):
            self.t0 = time.perf_counter()

    def __call__(self):
        if self.t0 is not None and time.perf_counter() >= self.flipped:
            self.polled_after += 1
            return True
        return False


def cancelled_render(esc, desc=None):
    desc = big_scene() if desc is None else desc
    out = render(desc, progress=esc.progress, should_cancel=esc)
    returned = time.perf_counter()
    assert out.cancelled and esc.polled_after, esc.stages[-3:]
    return out, returned - esc.flipped


def assert_complete(out, shape=(64, 80)):
    """Every tile written: finite passes of the right size, alpha 1 everywhere, the cloud
    in the middle, sky at the corners."""
    assert not out.cancelled and "march" in out.timings
    for name, p in out.passes.items():
        assert p.shape[:2] == shape and np.all(np.isfinite(p)), name
    comb = out.passes["Combined"]
    assert np.all(comb[..., 3] == 1.0)
    T = out.passes["Transmittance"]
    assert T[shape[0] // 2, shape[1] // 2].max() < 0.5 and np.all(T[0, 0] == 1.0)
    assert out.passes["Volume Single"][shape[0] // 2, shape[1] // 2].sum() > 0
    assert out.passes["Volume Multiple"][shape[0] // 2, shape[1] // 2].sum() > 0


@pytest.fixture(scope="module")
def reference():
    """One uninterrupted render of the scene (before any cancelled one)."""
    out = render(big_scene())
    assert_complete(out)
    return out


@pytest.mark.parametrize("delay,stage", [(0.3, None), (0.1, "Light attenuation: pt"),
                                         (0.2, "World light"), (0.05, "Light paths"),
                                         (0.1, "Tiles"), (0.0, "Pilot")])
def test_esc_returns_within_half_a_second(delay, stage, reference):
    esc = Esc(delay, stage)
    # the pilot plans adaptive sampling: more than one sample a pixel
    scene = {"Tiles": march_scene, "Pilot": lambda: big_scene(48, 320, 256, 16)}.get(stage,
                                                                                 big_scene)
    out, latency = cancelled_render(esc, scene())
    assert latency < LATENCY_S, f"{latency:.3f} s from Esc to return ({esc.stages[-1]})"
    if stage != "Tiles":
        assert "march" not in out.timings  # stopped in the precompute or the pilot
        assert ("pilot" in out.timings) == (stage == "Pilot")
    else:
        done = np.all(out.passes["Combined"][..., 3] == 1.0)
        assert not done  # stopped in the march, some tiles unwritten
    for name, p in out.passes.items():
        assert np.all(np.isfinite(p)), name


def test_memory_is_released_and_the_next_render_is_complete(reference):
    gc.collect()
    threads = threading.active_count()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        esc = Esc(0.3, "World light")  # the fields of every light are held by then
        out, latency = cancelled_render(esc)
        del out
        gc.collect()
        now, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    field_mb = (N + 2) ** 3 * (1 + 6 + 6) * 4 / 2 ** 20
    assert (peak - base) / 2 ** 20 > field_mb  # the precompute field was allocated ...
    assert (now - base) / 2 ** 20 < 2.0        # ... and given back
    assert threading.active_count() == threads  # no worker left behind
    again = render(big_scene())
    assert_complete(again)
    for name in reference.passes:
        np.testing.assert_array_equal(again.passes[name], reference.passes[name], err_msg=name)
