"""Chromatic media stay chromatic in multiple scattering: the paths of each colour channel
are absorbed, and spread, with that channel's coefficients (walk.level_table)."""
import numpy as np

from mpp_render.walk import RHO_TABLE, level_paths, level_table
from mpp_render.render import render

from test_stiff import cube, scene


def test_level_weights_integrate_each_channels_absorption():
    """Summed over the levels, the weights are int_0^l_max e^(-sigma_a rho l) dl of each
    channel exactly (the levels tile the path lengths), and a grey medium gives three equal
    columns, the same as one coefficient for all.  The levels' anisotropy is g g* e^(-l_k /
    l_tr) with the delta-scaled walk's g* = g / (1 + g) (g^2 e^(-l_k / l_tr) for g <= 0)."""
    h, n = 0.05, 8
    s3, a3 = np.array([2.0, 1.0, 0.5]), np.array([0.1, 1.0, 0.3])
    for g, g_walk in ((0.5, 0.5 / 1.5), (-0.3, -0.3)):
        table = level_table(g, s3, a3, h, n)
        assert table.shape == (n, len(RHO_TABLE), 6)
        for c in range(3):
            l_tr = 1.0 / (RHO_TABLE * s3[c] * (1 - g))
            l_max = level_paths(h, n, l_tr, g_walk)[-1][1]
            sa = RHO_TABLE * a3[c]
            want = -np.expm1(-sa * l_max) / sa
            np.testing.assert_allclose(table[:, :, c].sum(0), want, rtol=1e-9)
            np.testing.assert_allclose(table[:, :, 3 + c], g * g_walk * np.exp(
                -np.array([lk for _, _, lk in level_paths(h, n, l_tr, g_walk)]) / l_tr), rtol=1e-12)
    g = 0.5
    grey = level_table(g, np.full(3, 2.0), np.full(3, 0.3), h, n)
    np.testing.assert_array_equal(grey, level_table(g, 2.0, 0.3, h, n))
    np.testing.assert_array_equal(grey[..., 0], grey[..., 1])


def test_a_channel_that_absorbs_more_scatters_less_often():
    """A medium of grey extinction whose green is absorbed (albedo 0.9 red and blue, 0.5
    green): over the scattering coefficients' ratio squared (once for the first scattering,
    once for the last), green in Volume Multiple is 0.43 of red; 0.86 while the path weights
    used the channels' mean absorption (the world light's part was chromatic already)."""
    med = cube(sigma_s=1.8, sigma_a=0.2, g=0.3, n=16, size=4.0)
    med.sigma_s = np.array([1.8, 1.0, 1.8])
    med.sigma_a = np.array([0.2, 1.0, 0.2])
    out = render(scene([med], size=4.0, width=16, height=12))
    ms = out.passes["Volume Multiple"][..., :3].reshape(-1, 3).mean(0)
    assert ms[0] > 0 and np.isclose(ms[0], ms[2], rtol=1e-6)
    ratio = (ms[1] / ms[0]) / (1.0 / 1.8) ** 2
    print("green / red over the scattering ratio squared:", ratio)
    assert ratio < 0.6, ratio
