"""The Rendered viewport: Blender's ``view_update`` / ``view_draw`` on the progressive loop
of ``mpp_render.viewport``.

Blender calls, on its UI thread, ``view_update(context, depsgraph)`` when the scene changed
and ``view_draw(context, depsgraph)`` on every redraw (also while the view is navigated).
Neither waits for a render:

* ``view_update``: the depsgraph's updates say what changed (``changed_parts``: the lights,
  the geometry, the world, or everything on a new frame or a change of settings); only that
  is translated again (``translate.retranslate``), and the new scene goes to the loop, which
  abandons the work under way.  Unchanged precompute and grids come from ``cache.py``.
* ``view_draw``: a new view (orbit, zoom, a resized viewport) changes only the camera and
  restarts the loop; then the newest finished picture is drawn, stretched over the region,
  through Blender's display transform (``bind_display_space_shader``), and a redraw is asked
  for while pictures are still to come.

``ViewSession`` holds one viewport's state and is driven without a window by the tests and
``benchmarks/viewport.py``; ``Drawer.draw`` is the only part that needs a GPU.
"""
from __future__ import annotations

import dataclasses
from typing import Optional, Set

import numpy as np

from ..scene import Camera, SceneDescription
from ..viewport import Progressive, ViewImage
from .properties import settings_from_scene
from .translate import retranslate


def viewport_settings(scene):
    """The render settings of ``scene`` as the viewport uses them: ``viewport_samples`` rays
    per pixel, the Combined pass alone."""
    st = settings_from_scene(scene)
    return dataclasses.replace(st, samples=int(scene.mpp.viewport_samples), passes=["Combined"])


def changed_parts(updates) -> Set[str]:
    """What the depsgraph ``updates`` (``depsgraph.updates``) touch: 'lights', 'geometry'
    (volumes and opaque objects, their meshes, materials, node trees, images), 'world', or
    'all' for anything else (the scene and its settings, collections, view layers).  Camera
    objects and data touch nothing: the viewport draws its own view."""
    import bpy

    parts: Set[str] = set()
    T = bpy.types
    for u in updates:
        i = u.id
        if isinstance(i, T.Object):
            if i.type == "LIGHT":
                parts.add("lights")
            elif i.type != "CAMERA":
                parts.add("geometry")
        elif isinstance(i, T.Light):
            parts.add("lights")
        elif isinstance(i, T.World):
            parts.add("world")
        elif isinstance(i, T.NodeTree):      # a material's or the world's
            parts.update(("geometry", "world"))
        elif isinstance(i, (T.Mesh, T.Material, T.Volume, T.Image, T.Curve, T.MetaBall,
                            T.Texture)):
            parts.add("geometry")
        elif isinstance(i, T.Camera):
            continue
        else:
            parts.add("all")
    return parts


def parts_changed_by(change) -> Set[str]:
    """``changed_parts`` of the depsgraph updates Blender sends after ``change()`` (a callable
    that edits Blender data), read through a ``depsgraph_update_post`` handler: how a script,
    a test or benchmarks/viewport.py drives a ViewSession without a window, as view_update
    would be driven."""
    import bpy

    seen = []

    def handler(scene, depsgraph):
        seen.append(changed_parts(depsgraph.updates))

    bpy.app.handlers.depsgraph_update_post.append(handler)
    try:
        change()
        bpy.context.view_layer.update()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(handler)
    return set().union(*seen) if seen else set()


def view_key(camera: Camera) -> tuple:
    """What makes two viewport cameras the same view (matrix, view plane, size, clipping)."""
    return (camera.projection, np.asarray(camera.cam_to_world, np.float64).tobytes(),
            tuple(map(float, camera.plane)), int(camera.width), int(camera.height),
            float(camera.clip_start), float(camera.clip_end))


class ViewSession:
    """One viewport: the scene as last translated, its view, and the progressive loop.

    ``update(depsgraph, parts, camera)`` after a depsgraph change; ``look(camera)`` on every
    redraw (restarts the loop only when the view changed); ``latest()`` the picture to draw.
    ``close()`` stops the loop's thread."""

    def __init__(self, progressive: Optional[Progressive] = None):
        self.progressive = progressive if progressive is not None else Progressive()
        self.desc: Optional[SceneDescription] = None
        self.frame: Optional[int] = None
        self._view = None

    def update(self, depsgraph, parts: Set[str], camera: Camera) -> bool:
        """Translate what ``parts`` (changed_parts) name again, everything on a new frame,
        and restart the loop; False when nothing changed."""
        scene = depsgraph.scene_eval
        frame = int(scene.frame_current)
        if frame != self.frame:
            parts = {"all"}
        if not parts and self.desc is not None:
            return False
        self.desc = retranslate(depsgraph, viewport_settings(scene), self.desc, parts, camera)
        self.frame = frame
        self._view = view_key(camera)
        self.progressive.show(self.desc)
        return True

    def look(self, camera: Camera) -> bool:
        """The view is ``camera``: restart the loop if it changed (True), else nothing."""
        key = view_key(camera)
        if self.desc is None or key == self._view:
            return False
        self._view = key
        self.desc = dataclasses.replace(self.desc, camera=camera)
        self.progressive.show(self.desc)
        return True

    def latest(self) -> Optional[ViewImage]:
        return self.progressive.latest()

    def status(self) -> str:
        """The line the viewport shows: the stage drawn and what is still to come, or the
        error that stopped it."""
        if self.progressive.errors:
            return f"MPP: {self.progressive.errors[-1]}"
        img = self.latest()
        if img is None:
            return "MPP: rendering the first picture"
        h, w = img.rgba.shape[:2]
        state = "rendering" if self.progressive.busy else "done"
        return f"MPP: {w} x {h}, {img.seconds:.2f} s, {state}"

    def close(self) -> None:
        self.progressive.close()


def display_pixels(img: ViewImage) -> np.ndarray:
    """The picture as a GPU texture wants it: float32, flat, row 0 at the bottom."""
    return np.ascontiguousarray(img.rgba[::-1], np.float32).ravel()


class Drawer:
    """Keeps the GPU texture of the picture last drawn, made again only for a new one."""

    def __init__(self):
        self._texture = None
        self._shown = None

    def draw(self, engine, scene, img: ViewImage, width: int, height: int) -> None:
        """Draw ``img`` stretched over a ``width`` x ``height`` region through the scene's
        display transform (needs Blender's GPU context: ``view_draw`` only)."""
        import gpu
        from gpu_extras.presets import draw_texture_2d

        key = (img.generation, img.stage)
        if self._texture is None or self._shown != key:
            h, w = img.rgba.shape[:2]
            buf = gpu.types.Buffer("FLOAT", w * h * 4, display_pixels(img))
            self._texture = gpu.types.GPUTexture((w, h), format="RGBA16F", data=buf)
            self._shown = key
        gpu.state.blend_set("ALPHA_PREMULT")
        engine.bind_display_space_shader(scene)
        draw_texture_2d(self._texture, (0, 0), width, height)
        engine.unbind_display_space_shader()
        gpu.state.blend_set("NONE")
