"""The MPP ``RenderEngine``: a thin adapter from Blender's render loop to ``frame.render_depsgraph``.

One frame of one view layer flows one way::

    depsgraph --frame.render_depsgraph (translate + mpp_render.render.render)--> FrameRecord
              --write_result--> Blender render result (row 0 at the bottom)

The engine class only forwards to the plain functions below and hands each frame's record to
whoever collects it (``frame.collect``: the command line, the operators, the tests); the
engine keeps nothing between renders.

Animations (``blender -b file.blend -E MPP_RENDER -a``, ``render.render(animation=True)``):
Blender calls ``render`` once per frame and view layer and writes each frame's file.  What
did not change since an earlier frame or render -- the light and world-light precompute,
voxelised meshes, grids read from files -- is taken from ``mpp_render.cache``; the stats line
and the frame's record say which parts were reused.

``MPP_TEST_BREAK_AFTER_S`` (environment, seconds): when set, the render behaves as if Esc was
pressed that many seconds after it started (used by the tests; Blender's background mode has
no Esc).
"""
from __future__ import annotations

import os
import time
from typing import Callable, Optional

import bpy
import numpy as np

from ..passes import enabled_passes
from . import frame
from .frame import NO_MEDIA_MESSAGE, FrameRecord, TranslationError  # noqa: F401 (re-exported)

TEST_BREAK_ENV = "MPP_TEST_BREAK_AFTER_S"


def cancel_check(test_break: Callable[[], bool], start: float) -> Callable[[], bool]:
    """``should_cancel`` for the core: Blender's ``test_break`` (Esc), or true once
    ``MPP_TEST_BREAK_AFTER_S`` seconds have passed since ``start`` (``time.perf_counter``)."""
    after = os.environ.get(TEST_BREAK_ENV)
    deadline = start + float(after) if after not in (None, "") else None

    def should_cancel() -> bool:
        if deadline is not None and time.perf_counter() >= deadline:
            return True
        return bool(test_break())

    return should_cancel


def register_passes(engine, scene, renderlayer) -> None:
    """Register exactly the passes ``render_frame`` fills: Combined, Volume Single, Volume
    Multiple (only with multiple scattering on), Transmittance, Depth."""
    multiple = scene.mpp.multiple if hasattr(scene, "mpp") else True
    for p in enabled_passes(multiple):
        engine.register_pass(scene, renderlayer, p.name, p.channels, p.chan_id, p.kind)


def write_result(engine, passes: dict, layer_name: str, width: int, height: int) -> None:
    """Copy ``passes`` (name -> (H, W, C) float, row 0 at the top) into a new render result of
    view layer ``layer_name``; rows are flipped to Blender's bottom-up order.  Passes the
    result does not hold (not registered) are skipped."""
    result = engine.begin_result(0, 0, width, height, layer=layer_name)
    try:
        layer = result.layers[0]
        for name, arr in passes.items():
            rp = layer.passes.find_by_name(name, "")
            if rp is None:
                continue
            if arr.shape[:2] != (height, width) or arr.shape[2] != rp.channels:
                raise ValueError(f"pass {name}: got {arr.shape}, result wants "
                                 f"({height}, {width}, {rp.channels})")
            rp.rect.foreach_set(np.ascontiguousarray(arr[::-1], np.float32).ravel())
    finally:
        engine.end_result(result)


def progress_reporter(engine) -> Callable[[float, str], None]:
    """``progress(fraction, message)`` for the core: Blender's progress bar and stats line."""

    def progress(fraction: float, message: str) -> None:
        engine.update_progress(float(min(max(fraction, 0.0), 1.0)))
        engine.update_stats("MPP", message)

    return progress


def render_frame(engine, depsgraph) -> Optional[FrameRecord]:
    """Render one frame of ``depsgraph``'s view layer into ``engine``'s result, reporting
    every warning.  Returns the frame's record; None when the scene could not be translated
    (an error is reported)."""
    start = time.perf_counter()
    should_cancel = cancel_check(engine.test_break, start)
    scene = depsgraph.scene_eval
    width, height = int(engine.resolution_x), int(engine.resolution_y)
    told = []

    def tell(warnings):   # what the engine leaves out, said before the render runs
        for msg in warnings:
            engine.report({'WARNING'}, msg)
            told.append(msg)

    try:
        rec = frame.render_depsgraph(depsgraph, width, height,
                                     camera_override=engine.camera_override,
                                     progress=progress_reporter(engine),
                                     should_cancel=should_cancel, on_translated=tell)
    except TranslationError as e:  # say why instead of a black frame
        engine.report({'ERROR'}, f"MPP: cannot translate the scene: {e}")
        return None
    out = rec.output
    for msg in out.warnings:
        if msg not in told:
            engine.report({'WARNING'}, msg)

    t_write = time.perf_counter()
    write_result(engine, out.passes, rec.view_layer, width, height)
    rec.write_s = time.perf_counter() - t_write
    if out.cancelled:
        engine.report({'INFO'}, "MPP: render cancelled; the passes hold the finished tiles")
    reused = out.stats.get("reused")
    if reused:
        engine.update_stats("MPP", f"Frame {scene.frame_current}: reused the precompute of "
                            + " and ".join(reused))
    engine.update_progress(1.0)
    return rec


class MPPRenderEngine(bpy.types.RenderEngine):
    """Volumes (smoke, clouds, fog) by ray marching with most-probable-path multiple
    scattering.  Final renders (``render``); the Rendered viewport (``view_update`` /
    ``view_draw``, blender/viewport.py: a progressive picture rendered off the UI thread);
    Material Preview draws with EEVEE (``bl_use_eevee_viewport``)."""

    bl_idname = "MPP_RENDER"
    bl_label = "MPP"
    bl_use_preview = False
    bl_use_eevee_viewport = True   # Material Preview shading draws with EEVEE
    bl_use_postprocess = True
    bl_use_shading_nodes_custom = False

    def render(self, depsgraph):
        frame.deliver(render_frame(self, depsgraph))

    def update_render_passes(self, scene=None, renderlayer=None):
        register_passes(self, scene, renderlayer)

    # -- the Rendered viewport ------------------------------------------------------------

    def view_update(self, context, depsgraph):
        from . import viewport
        if getattr(context, "region_data", None) is None:   # not a 3D viewport's region
            return
        session = getattr(self, "_view", None)
        if session is None:
            session = self._view = viewport.ViewSession()
            parts = {"all"}
        else:
            parts = viewport.changed_parts(depsgraph.updates)
        camera = region_camera(self, context)
        if camera is not None:
            session.update(depsgraph, parts, camera)

    def view_draw(self, context, depsgraph):
        from . import viewport
        session = getattr(self, "_view", None)
        if session is None or getattr(context, "region_data", None) is None:
            return
        camera = region_camera(self, context)
        if camera is None:
            return
        session.look(camera)
        img = session.latest()
        if img is not None:
            if getattr(self, "_drawer", None) is None:
                self._drawer = viewport.Drawer()
            self._drawer.draw(self, depsgraph.scene, img, context.region.width,
                              context.region.height)
        self.update_stats("", session.status())
        if session.progressive.busy:
            self.tag_redraw()   # poll for the next picture

    def __del__(self):
        session = getattr(self, "_view", None)
        if session is not None:
            session.close()


def region_camera(engine, context):
    """The viewport's own view as a camera (translate/view.py), the region's size in pixels;
    None, said on ``engine``'s stats line, for a view the engine cannot render from."""
    from .translate.view import camera_from_region
    region = context.region
    try:
        return camera_from_region(context.region_data, int(region.width), int(region.height))
    except ValueError as e:
        engine.update_stats("", f"MPP: {e}")
        return None


def register():
    """Register the engine class (a second call does nothing)."""
    if not MPPRenderEngine.is_registered:
        bpy.utils.register_class(MPPRenderEngine)


def unregister():
    if MPPRenderEngine.is_registered:
        bpy.utils.unregister_class(MPPRenderEngine)
