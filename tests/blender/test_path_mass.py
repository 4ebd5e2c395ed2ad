"""The traced paths' M (precompute/lightpaths.py) on the sparse edges of a procedural cloud:
each lattice point's density mass integrates its tent over the voxels' cells, as the paths
read the nearest voxel's density, so a point that only a sliver of dense voxels reaches has
no spike (weighing the voxel centres alone gave one lattice point of p_noise_cloud M = 1295,
1700 times the 99th percentile: a firefly in the render)."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import precompute as P  # noqa: E402
from mpp_render.blender import batch  # noqa: E402
from mpp_render.blender.properties import settings_from_scene  # noqa: E402
from mpp_render.blender.translate import scene_from_depsgraph  # noqa: E402
from mpp_render.media import prepare  # noqa: E402
from mpp_render.precompute.source import box_tent_weights, tent_restrict  # noqa: E402


@pytest.mark.parametrize("stride", [1, 2, 3, 4])
def test_box_weights_integrate_the_tent_over_each_voxel(stride):
    w = box_tent_weights(stride)
    assert sum(w.values()) == pytest.approx(1.0, abs=1e-12)
    for t, wt in w.items():     # midpoint rule over the voxel's width
        u = t - 0.5 + (np.arange(200_000) + 0.5) / 200_000
        assert wt == pytest.approx(np.mean(np.maximum(0.0, 1.0 - np.abs(u) / stride)) / stride,
                                   abs=1e-9)
    # a voxel a whole stride from a lattice point lies beyond the point tent, not the boxed one
    a = np.zeros(4 * stride + 1)
    a[stride] = 1.0
    assert tent_restrict(a, 0, stride, 5)[0] == 0.0
    assert tent_restrict(a, 0, stride, 5, boxed=True)[0] == pytest.approx(w[stride])


def test_no_spike_in_m_on_a_textured_clouds_sparse_edges(scenes_dir):
    batch.register()
    bpy.ops.wm.open_mainfile(filepath=str(scenes_dir / "p_noise_cloud" / "scene.blend"))
    dg = bpy.context.evaluated_depsgraph_get()
    desc = scene_from_depsgraph(dg, settings_from_scene(dg.scene_eval))
    media = [prepare(m) for m in desc.media]
    pre = P.precompute(media, desc.lights, desc.world, desc.camera, multiple=True,
                       multiple_paths=200_000, multiple_resolution=64, n_dirs=8)
    m = pre.multiple[0][0].levels[0][..., 0]
    p99 = np.percentile(m[m > 0], 99)
    print(f"M max {m.max():.3f}, 99th percentile {p99:.3f}")
    assert m.max() <= 50.0 * p99
