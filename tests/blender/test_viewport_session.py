"""The Rendered viewport's Blender side (mpp_render/blender/viewport.py) without a window:
what a depsgraph update touches, read from Blender's own updates; a ViewSession that
translates again only what changed, restarts on a new view, and ends on the F12 render of
the same view; the engine's view_update / view_draw called as Blender calls them, with the
GPU drawing recorded instead (it needs a window)."""
import time
import types

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import frame, viewport  # noqa: E402
from mpp_render.blender.translate.view import camera_from_matrices  # noqa: E402

from parts import add_camera, add_cube, add_light, mpp_output  # noqa: E402

pytestmark = pytest.mark.usefixtures("registered")

W, H = 48, 27


@pytest.fixture
def small(empty_scene):
    sc = mpp_output(empty_scene, W, H, samples=2, voxels=16)
    sc.mpp.viewport_samples = 2
    sc.mpp.multiple_paths = 20000
    cube = add_cube(sc, "Cube", scale=(0.8, 0.8, 0.8))
    light = add_light(sc, "Lamp", "POINT", energy=200.0, location=(1.5, -2.0, 2.0))
    cam = add_camera(sc, distance=6.0)
    bpy.context.view_layer.update()
    return sc, cube, light, cam


def view_of(sc, cam):
    """The Camera a viewport looking through ``cam`` would give (translate.view)."""
    dg = bpy.context.evaluated_depsgraph_get()
    window = cam.calc_matrix_camera(dg, x=W, y=H)
    return camera_from_matrices(cam.matrix_world.inverted(), window, W, H)


updates_after = viewport.parts_changed_by


def test_changed_parts_read_blenders_updates(small):
    sc, cube, light, cam = small

    def move_light():
        light.location.x += 0.2

    def more_energy():
        light.data.energy *= 2

    def denser():
        mat = cube.data.materials[0]
        node = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeVolumePrincipled")
        node.inputs["Density"].default_value *= 2

    def move_cube():
        cube.location.z += 0.1

    def move_camera():
        cam.location.x += 0.1

    assert updates_after(move_light) == {"lights"}
    assert updates_after(more_energy) == {"lights"}
    assert "geometry" in updates_after(denser) and "lights" not in updates_after(denser)
    assert updates_after(move_cube) == {"geometry"}
    assert updates_after(move_camera) == set()


def test_a_session_translates_only_what_changed_and_ends_on_the_f12_render(small, warm):
    sc, cube, light, cam = small
    session = viewport.ViewSession()
    try:
        dg = bpy.context.evaluated_depsgraph_get()
        view = view_of(sc, cam)
        assert session.update(dg, {"all"}, view)
        first = session.progressive.wait(1, timeout=120)
        assert first is not None and first.rgba.shape == (H, W, 4)
        f12 = frame.render_depsgraph(dg, W, H).output.passes["Combined"]
        assert f12[..., :3].max() > 0
        np.testing.assert_allclose(first.rgba, f12, rtol=0, atol=1e-4 * f12.max())
        medium = session.desc.media[0]

        light.location.x += 0.5                    # a moved light: the lights alone again
        bpy.context.view_layer.update()
        assert session.update(dg, {"lights"}, view)
        assert session.desc.media[0] is medium
        assert not np.allclose(session.desc.lights[0].position, [1.5, -2.0, 2.0])
        moved = session.progressive.wait(2, timeout=120)
        assert moved is not None and not np.array_equal(moved.rgba, first.rgba)

        assert not session.update(dg, set(), view)  # nothing changed: nothing restarts
        assert not session.look(view)
        cam.location.x += 0.3                      # the view moves: the camera alone
        bpy.context.view_layer.update()
        assert session.look(view_of(sc, cam))
        assert session.desc.media[0] is medium
        orbit = session.progressive.wait(3, timeout=120)
        assert orbit is not None and not np.array_equal(orbit.rgba, moved.rgba)

        sc.frame_set(sc.frame_current + 1)         # a new frame: everything again
        assert session.update(dg, set(), view_of(sc, cam))
        assert session.desc.media[0] is not medium
        assert session.progressive.wait(4, timeout=120) is not None
        assert "done" in session.status() and not session.progressive.errors
    finally:
        session.close()


def test_display_pixels_put_row_0_at_the_bottom():
    from mpp_render.viewport import ViewImage
    rgba = np.zeros((3, 2, 4), np.float32)
    rgba[0, :, 0] = 1.0                            # the top row is red
    flat = viewport.display_pixels(ViewImage(rgba, 0, True, 0.0, 1))
    assert flat.dtype == np.float32 and flat.shape == (24,)
    assert flat.reshape(3, 2, 4)[2, :, 0].tolist() == [1.0, 1.0]
    assert flat.reshape(3, 2, 4)[0, :, 0].tolist() == [0.0, 0.0]


class FakeEngine:
    """What view_update / view_draw use of a RenderEngine (Blender makes the real one only
    for a window's viewport)."""

    def __init__(self):
        self.stats, self.redraws = [], 0

    def update_stats(self, a, b):
        self.stats.append(b)

    def tag_redraw(self):
        self.redraws += 1


def test_the_engines_view_callbacks_draw_the_pictures_as_they_come(small, monkeypatch):
    from mpp_render.blender.engine import MPPRenderEngine
    sc, cube, light, cam = small
    drawn = []

    class Recorder:
        def draw(self, engine, scene, img, width, height):
            drawn.append((img.generation, img.stage, img.rgba.shape, width, height))

    monkeypatch.setattr(viewport, "Drawer", Recorder)
    dg = bpy.context.evaluated_depsgraph_get()
    window = cam.calc_matrix_camera(dg, x=W, y=H)
    region_data = types.SimpleNamespace(view_matrix=cam.matrix_world.inverted(),
                                        window_matrix=window)
    context = types.SimpleNamespace(region=types.SimpleNamespace(width=W, height=H),
                                    region_data=region_data)
    engine = FakeEngine()
    MPPRenderEngine.view_draw(engine, context, dg)          # before any update: nothing
    assert drawn == [] and engine.stats == []
    MPPRenderEngine.view_update(engine, context, dg)
    try:
        session = engine._view
        deadline = time.perf_counter() + 120
        while time.perf_counter() < deadline:               # Blender redraws while asked to
            MPPRenderEngine.view_draw(engine, context, dg)
            if not session.progressive.busy and drawn and drawn[-1][1] == 2:
                break
            time.sleep(0.01)
        MPPRenderEngine.view_draw(engine, context, dg)
        stages_seen = sorted({d[1] for d in drawn})
        assert stages_seen[-1] == 2 and drawn[-1][2] == (H, W, 4)
        assert all(d[3:] == (W, H) for d in drawn)         # stretched over the region
        assert engine.redraws >= 1 and "done" in engine.stats[-1]
        redraws = engine.redraws
        MPPRenderEngine.view_draw(engine, context, dg)      # finished: no more redraws asked
        assert engine.redraws == redraws
    finally:
        MPPRenderEngine.__del__(engine)
    assert not session.progressive._thread.is_alive()


def test_the_view_callbacks_pass_over_a_region_without_a_view_and_say_why_a_view_fails(small):
    from mathutils import Matrix
    from mpp_render.blender.engine import MPPRenderEngine
    dg = bpy.context.evaluated_depsgraph_get()
    engine = FakeEngine()
    no_view = types.SimpleNamespace(region=types.SimpleNamespace(width=W, height=H),
                                    region_data=None)
    MPPRenderEngine.view_update(engine, no_view, dg)
    MPPRenderEngine.view_draw(engine, no_view, dg)
    assert getattr(engine, "_view", None) is None and engine.stats == []
    skew = Matrix.Identity(4)
    skew[3][2], skew[3][3], skew[0][1] = -1.0, 0.0, 0.5      # perspective with a skew term
    bad = types.SimpleNamespace(region=no_view.region, region_data=types.SimpleNamespace(
        view_matrix=Matrix.Identity(4), window_matrix=skew))
    MPPRenderEngine.view_update(engine, bad, dg)
    try:
        assert engine.stats and engine.stats[-1].startswith("MPP: ")
        assert engine._view.desc is None                   # nothing rendered from it
    finally:
        MPPRenderEngine.__del__(engine)
