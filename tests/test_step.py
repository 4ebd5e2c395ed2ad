"""The march step (render.auto_step): Step Size when the user sets one, else
``Tuning.step_voxels`` of the finest voxel's side."""
import dataclasses

import numpy as np

from mpp_render.render import auto_step, prepare_media

from test_cache import scene


def test_the_step_is_a_share_of_the_finest_voxel_unless_the_user_sets_one():
    desc = scene()
    media = prepare_media(desc.media, [])
    voxel = min(pm.voxel_size for pm in media)
    assert np.isclose(voxel, 2.0 / 18)                       # the test cloud: 18 voxels over 2 m
    assert np.isclose(auto_step(desc, media), 0.5 * voxel)   # the default: half a voxel
    tuned = dataclasses.replace(desc, settings=dataclasses.replace(
        desc.settings, tuning=dataclasses.replace(desc.settings.tuning, step_voxels=1.0)))
    assert np.isclose(auto_step(tuned, media), voxel)
    user = dataclasses.replace(desc, settings=dataclasses.replace(desc.settings, step_size=0.03))
    assert auto_step(user, media) == 0.03
    assert auto_step(desc, []) == 1.0                         # nothing to march
