"""One frame rendered with the MPP core, handed back as a return value.

``render_depsgraph(depsgraph, width, height)`` translates an evaluated depsgraph into a
``SceneDescription`` and renders it with ``mpp_render.render.render``; it returns a
``FrameRecord`` (the core's ``RenderOutput``: passes, timings, stats, warnings; the
translation time; the view layer and frame).  It knows nothing of Blender's render result:
``engine.MPPRenderEngine.render`` calls it and copies the passes into the result.

Blender's render operator (``bpy.ops.render.render``) returns no value, and only a render
through it gets Blender's render-mode depsgraph (objects hidden for render left out, render
levels of modifiers).  A caller that starts the operator and wants the frames' records opens
``collect()`` around it: the engine delivers each frame's record to the collectors open at the
time, and nothing is kept once they close::

    with collect() as frames:
        bpy.ops.render.render()
    rec = frames[-1]

``render_mpp(**operator_kwargs)`` does exactly that and returns the last frame's record.
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Callable, List, Optional

NO_MEDIA_MESSAGE = "MPP: no volumes in the scene; rendering the background and surfaces only"


@dataclass
class FrameRecord:
    """One frame rendered by MPP.  ``output``: the core's ``RenderOutput`` (passes with row 0
    at the top, timings, stats, warnings, cancelled); ``translate_s``: seconds from depsgraph
    to scene description; ``write_s``: seconds the engine took to copy the passes into
    Blender's render result (0 until it did); ``view_layer``: the layer's name."""

    output: object
    translate_s: float
    write_s: float
    view_layer: str
    frame: int = 0


class TranslationError(Exception):
    """The depsgraph could not be read into a scene description at all."""


def render_depsgraph(depsgraph, width: int, height: int, camera_override=None,
                     progress: Optional[Callable[[float, str], None]] = None,
                     should_cancel: Optional[Callable[[], bool]] = None,
                     on_translated: Optional[Callable[[List[str]], None]] = None) -> FrameRecord:
    """Render the current frame of ``depsgraph``'s view layer (``width`` x ``height`` pixels,
    the camera ``camera_override`` or the scene's) with the MPP core and return its record.
    A scene without volumes gets ``NO_MEDIA_MESSAGE`` among its warnings.
    ``on_translated(warnings)`` is called with what the translation left out or changed before
    the render starts (the engine reports it then, not after the render).  Raises
    ``TranslationError`` when the scene cannot be translated."""
    from ..render import render
    from .properties import settings_from_scene
    from .translate import scene_from_depsgraph

    start = time.perf_counter()
    scene = depsgraph.scene_eval
    if progress is not None:
        progress(0.0, "Translating scene")
    try:
        desc = scene_from_depsgraph(depsgraph, settings_from_scene(scene),
                                    camera_override=camera_override,
                                    width=int(width), height=int(height))
    except Exception as e:  # a scene we cannot read at all: the caller says why
        raise TranslationError(str(e)) from e
    translate_s = time.perf_counter() - start
    if not desc.media and desc.world.volume is None:
        desc.warnings.append(NO_MEDIA_MESSAGE)
    if on_translated is not None:
        on_translated(list(desc.warnings))
    out = render(desc, progress=progress, should_cancel=should_cancel)
    return FrameRecord(out, translate_s, 0.0, depsgraph.view_layer.name,
                       int(scene.frame_current))


_COLLECTORS: List[list] = []  # the lists of the collect() blocks open now


@contextlib.contextmanager
def collect():
    """A list that receives the record of every frame the engine renders inside the block."""
    frames: list = []
    _COLLECTORS.append(frames)
    try:
        yield frames
    finally:
        _COLLECTORS.remove(frames)


def deliver(record: Optional[FrameRecord]) -> None:
    """Hand ``record`` (None: the frame failed) to the open collectors (the engine's call)."""
    if record is not None:
        for frames in _COLLECTORS:
            frames.append(record)


def render_mpp(**operator_kwargs) -> FrameRecord:
    """Run ``bpy.ops.render.render(**operator_kwargs)`` (the scene's engine must be MPP) and
    return the record of the last frame MPP rendered.  RuntimeError when it rendered none
    (another engine, or a scene that could not be translated: see the reports)."""
    import bpy

    with collect() as frames:
        bpy.ops.render.render(**operator_kwargs)
    if not frames:
        raise RuntimeError("the MPP engine produced no image (see the reports above)")
    return frames[-1]
