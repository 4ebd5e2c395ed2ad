"""A light's paths weigh the same in media that overlap (precompute/run.py path_shares,
lightpaths.across_media): a medium the light barely reaches inside another takes as few of
the Paths as the power of its starts asks; media apart take the whole setting."""
from __future__ import annotations

import numpy as np
import pytest

from mpp_render.media import prepare
from mpp_render.precompute import run as R
from mpp_render.precompute.lightpaths import across_media
from mpp_render.scene import Camera, Light, Medium, World


def box(name, n, size, centre, sigma_t, albedo=0.9):
    """A homogeneous cube of ``n`` voxels a side, ``size`` m, at ``centre``."""
    vox = size / n
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([vox] * 3)
    i2w[:3, 3] = np.asarray(centre, float) - 0.5 * size + 0.5 * vox
    return prepare(Medium(name, np.ones((n, n, n), np.float32), i2w,
                          np.full(3, albedo * sigma_t), np.full(3, (1 - albedo) * sigma_t), 0.0))


def camera():
    cam = np.eye(4)
    cam[:3, 3] = [0.0, -8.0, 0.0]
    cam[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    return Camera("PERSP", cam, 8, 8, (-0.3, 0.3, -0.3, 0.3))


def test_shares_follow_the_power():
    assert across_media([39.9, 1.5]) == pytest.approx([1.0, 1.5 / 39.9])
    assert across_media([2.0, 4.0, 0.0]) == pytest.approx([0.5, 1.0, 0.0])
    assert across_media([0.0, 0.0]) == [1.0, 1.0]


def traced_counts(media, monkeypatch):
    """{medium name: paths asked of traced_multiple} for one sun over ``media``."""
    got = {}
    real = R.traced_multiple

    def spy(pm, fld, light, channel, camera, n_paths, *a, **k):
        got[pm.medium.name] = n_paths
        return real(pm, fld, light, channel, camera, n_paths, *a, **k)

    monkeypatch.setattr(R, "traced_multiple", spy)
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.0, 0.0, -1.0]))
    R.precompute(media, [sun], World(), camera(), multiple=True, multiple_paths=20_000,
                 multiple_resolution=12)
    return got


def test_a_medium_in_anothers_shadow_takes_fewer_paths(monkeypatch):
    outer = box("outer", 24, 2.0, (0, 0, 0), 3.0)          # optical depth 3 above the inner
    inner = box("inner", 12, 0.5, (0, 0, 0), 3.0)
    got = traced_counts([outer, inner], monkeypatch)
    assert got["outer"] == 20_000
    assert 1 <= got["inner"] < 0.2 * 20_000


def test_media_apart_take_the_whole_setting(monkeypatch):
    left = box("left", 16, 1.0, (-2, 0, 0), 3.0)
    right = box("right", 8, 0.25, (2, 0, 0), 3.0)
    got = traced_counts([left, right], monkeypatch)
    assert got == {"left": 20_000, "right": 20_000}


def test_the_shares_count_the_light_the_surfaces_reflect_into_a_medium(monkeypatch):
    """With a ground, a medium's paths also start where the ground reflects the light into
    it: the shares weigh every start (lightpaths.start_power), so each light's paths take,
    per overlapping medium, the setting times the power traced_multiple then starts with
    over the most of the two (the repeat scene: a spot that barely reaches the box directly
    lights it off the ground)."""
    from test_repeat import scene
    from mpp_render.render import render
    got = {}
    real = R.traced_multiple

    def spy(pm, fld, light, channel, camera, n_paths, *a, **k):
        out = real(pm, fld, light, channel, camera, n_paths, *a, **k)
        got[(pm.medium.name, light.name)] = (n_paths, out[6][0])
        return out

    monkeypatch.setattr(R, "traced_multiple", spy)
    render(scene(2, samples=1))
    for light in ("sun", "pt", "spot", "area"):
        (na, pa), (nb, pb) = got[("cloud", light)], got[("box", light)]
        top = max(pa, pb)
        assert na == int(np.ceil(20000 * pa / top)) and nb == int(np.ceil(20000 * pb / top))
    assert got[("box", "spot")][0] > 10000   # 1 path when the ground's light was left out
