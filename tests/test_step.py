"""The march step (render.auto_step): Step Size when the user sets one, else
``Tuning.step_voxels`` of the finest voxel's side, or ``Tuning.smooth_step_voxels`` where the
light in the media is as smooth as their voxels (media.smooth_light)."""
import dataclasses

import numpy as np

from mpp_render.render import auto_step, prepare_media

from test_cache import scene


def test_the_step_is_a_share_of_the_finest_voxel_unless_the_user_sets_one():
    desc = scene()
    media = prepare_media(desc.media, [])
    voxel = min(pm.voxel_size for pm in media)
    assert np.isclose(voxel, 2.0 / 18)                       # the test cloud: 18 voxels over 2 m
    # the default with its lamp 6 voxels from the cloud: half a voxel
    assert np.isclose(auto_step(desc, media, desc.lights), 0.5 * voxel)
    tuned = dataclasses.replace(desc, settings=dataclasses.replace(
        desc.settings, tuning=dataclasses.replace(desc.settings.tuning, step_voxels=1.0)))
    assert np.isclose(auto_step(tuned, media, desc.lights), voxel)
    user = dataclasses.replace(desc, settings=dataclasses.replace(desc.settings, step_size=0.03))
    assert auto_step(user, media) == 0.03
    assert auto_step(desc, []) == 1.0                         # nothing to march


def with_lights(desc, lights, **media_kw):
    media = [dataclasses.replace(m, **media_kw) for m in desc.media]
    return dataclasses.replace(desc, lights=lights, media=media)


def test_a_voxel_a_step_only_where_the_light_is_as_smooth_as_the_voxels():
    """The test cloud (a density grid, 18 voxels over 2 m) steps a whole voxel under a sun,
    and under a lamp farther than Tuning.disc_voxels voxels from its box; half a voxel with
    a lamp nearer (its 1 / r^2 changes within a voxel), with any spot (its cone's edge), for
    a mesh volume's sharp surface and for a glowing grid.  The longer step keeps to Tuning.smooth_step_tau of
    optical depth in the densest voxel (this cloud's: 0.7), and a cloud ten times as dense
    steps half a voxel."""
    from mpp_render.scene import Light
    desc = scene()
    voxel = 2.0 / 18
    reach = desc.settings.tuning.disc_voxels * voxel            # 1.78 m
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.3, 0.2, -0.93]))

    def step(lights, **kw):
        d = with_lights(desc, lights, **kw)
        media = prepare_media(d.media, [])
        return auto_step(d, media, d.lights) / voxel

    def lamp(x, kind="POINT"):
        return Light(kind, "lamp", np.full(3, 100.0), position=np.array([x, 0.0, 0.0]), radius=0.1)

    tau = float(np.max(desc.media[0].density)) * 4.4 * voxel
    assert 0.6 < tau < 0.8
    smooth = 0.5 / tau                                                # voxels
    assert np.isclose(step([sun]), smooth)
    assert np.isclose(step([sun], density=desc.media[0].density * 0.5), 1.0)
    assert np.isclose(step([sun], density=desc.media[0].density * 10.0), 0.5)
    assert np.isclose(step([sun, lamp(1.0 + reach + 0.1)]), smooth)  # beyond the reach
    assert np.isclose(step([sun, lamp(1.0 + reach - 0.1)]), 0.5)     # within it
    assert np.isclose(step([sun, lamp(0.0)]), 0.5)                   # inside the cloud
    assert np.isclose(step([sun, lamp(50.0, "SPOT")]), 0.5)          # a spot's cone edge
    assert np.isclose(step([sun, Light("POINT", "off", np.zeros(3))]), smooth)   # a dark lamp
    assert np.isclose(step([sun], source="MESH"), 0.5)              # a sharp surface
    assert np.isclose(step([sun], emission=np.full(3, 0.1)), 0.5)   # a glow


def test_the_distance_to_a_grid_box_is_a_lower_bound():
    """media.box_distance: 0 inside, the distance to the voxel centres' box outside (exact
    for a uniform scale, a lower bound for a stretched one)."""
    from mpp_render.media import box_distance
    desc = scene()
    pm = prepare_media(desc.media, [])[0]
    lo = pm.to_world(np.zeros((1, 3)))[0]
    hi = pm.to_world(np.array(pm.grid.shape, float)[None] - 1.0)[0]
    assert box_distance(pm, (lo + hi) / 2) == 0.0
    assert np.isclose(box_distance(pm, hi + [0.5, 0.0, 0.0]), 0.5)
    assert np.isclose(box_distance(pm, hi + [0.3, 0.4, 0.0]), 0.5)


def test_long_steps_are_unbiased_to_the_rays_end():
    """A uniform 8^3 grid (0.25 m voxels, density 0.2 /m, albedo 1, isotropic) under a sun
    straight above, seen straight down by an orthographic camera: the light to a point and
    from it to the camera cross the same depth, so the single scattering is exactly
    E / (4 pi) (1 - exp(-2 tau)) / 2, tau the grid's optical depth top to bottom (its 8
    voxels: 7 between the first and last centres, half a voxel of fade beyond each).  At
    steps that do not divide the ray, its last step ends early: its point is drawn on that
    shorter step (a point drawn on the whole step and clamped to the ray's end, as before,
    read the zero density past the grid: 3.4 % dark at a step of a voxel)."""
    from mpp_render.render import render
    from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings
    n, vox, dens = 8, 0.25, 0.2
    i2w = np.diag([vox, vox, vox, 1.0])
    med = Medium("box", np.ones((n, n, n), np.float32), i2w, np.full(3, dens), np.zeros(3),
                 0.0)
    cam = np.eye(4)
    cam[:3, 3] = [0.875, 0.875, 6.0]                         # over the middle, looking down
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.0, 0.0, -1.0]))
    tau = dens * n * vox
    want = 3.0 / (4.0 * np.pi) * (1.0 - np.exp(-2.0 * tau)) / 2.0
    for step in (0.25, 0.4, 0.07):
        desc = SceneDescription(Camera("ORTHO", cam, 12, 12, (-0.6, 0.6, -0.6, 0.6)),
                                media=[med], lights=[sun],
                                settings=Settings(samples=16, multiple=False, step_size=step,
                                                  noise_threshold=0.0))
        got = render(desc).passes["Volume Single"][..., :3].mean()
        assert abs(got / want - 1.0) < 0.006, (step, got / want)
