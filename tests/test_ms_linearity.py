"""Multiple scattering is linear in the light: doubling every light's power (and the sky)
doubles every radiance pass, and changes neither transmittance nor depth."""
import copy

import numpy as np

from mpp_render.render import render
from mpp_render.scene import Light

from test_stiff import cube, scene


def lit_scene(world):
    lights = [Light("SUN", "sun", np.array([3.0, 2.5, 2.0]), direction=np.array([0.3, 0.2, -0.93])),
              Light("POINT", "lamp", np.array([40.0, 60.0, 80.0]), position=np.array([1.8, -0.6, 0.4]),
                    radius=0.1)]
    rng = np.random.default_rng(7)
    grid = (rng.random((10, 10, 10)) * 2.0).astype(np.float32)
    media = [cube(sigma_s=3.0, sigma_a=0.4, g=0.6, n=10, grid=grid),
             cube(sigma_s=1.0, sigma_a=0.0, g=0.0, n=6, size=1.0, source="MESH")]
    return scene(media, lights, width=16, height=12, world=world)


def doubled(desc):
    d = copy.deepcopy(desc)
    for light in d.lights:
        light.strength = 2.0 * np.asarray(light.strength)
    d.world.color = 2.0 * np.asarray(d.world.color)
    return d


def test_doubling_every_light_doubles_every_radiance_pass():
    for world in (0.0, 0.2):
        desc = lit_scene(world)
        a = render(desc).passes
        b = render(doubled(desc)).passes
        assert a["Volume Multiple"].max() > 0 and a["Volume Single"].max() > 0
        for name in ("Volume Single", "Volume Multiple"):
            assert np.allclose(b[name], 2.0 * a[name], rtol=1e-5, atol=1e-9), name
        assert np.allclose(b["Combined"][..., :3], 2.0 * a["Combined"][..., :3], rtol=1e-5, atol=1e-9)
        assert np.array_equal(b["Transmittance"], a["Transmittance"])
        assert np.array_equal(b["Depth"], a["Depth"])


def test_one_light_at_a_time_adds_up():
    """Passes of the two lights rendered separately sum to the passes of both together."""
    desc = lit_scene(0.0)
    both = render(desc).passes
    parts = []
    for keep in range(2):
        d = copy.deepcopy(desc)
        for i, light in enumerate(d.lights):
            if i != keep:
                light.strength = np.zeros(3)
        parts.append(render(d).passes)
    for name in ("Volume Single", "Volume Multiple"):
        assert np.allclose(parts[0][name] + parts[1][name], both[name], rtol=1e-5, atol=1e-9), name
