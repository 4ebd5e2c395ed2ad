"""The Rendered viewport's progressive loop, run off the caller's thread (no bpy).

``Progressive.show(desc)`` hands over the scene as the viewport sees it now; a worker thread
renders it in stages (``stages``), each a whole frame through ``render.render``, and
``latest()`` returns the newest finished one.  A new ``show`` abandons the work under way
(its render's ``should_cancel`` turns true, so a precompute or a march stops within one
chunk or tile) and starts again from the first stage.  The caller's thread (Blender's UI)
never waits: it draws whatever ``latest()`` holds.

The stages (``Stage``; the defaults, ``stages(samples)``):

1. *coarse*: a quarter of the resolution along each side, 1 sample per pixel, multiple
   scattering from ``COARSE_PATHS`` of the light paths, and the precompute of an earlier
   camera position of the same scene when the cache holds one (``render(any_camera=True)``,
   cache.precompute_cached): while the view orbits, only this small march runs;
2. *full resolution, 1 sample*, still with the coarse share of the paths (its precompute is
   the coarse stage's, or this view's own after an orbit);
3. *refined*: the scene's own settings at 4, 16, ... samples up to the viewport's samples.
   The last stage is the F12 render of the same view with those samples, bit for bit; each
   stage replaces the one before.

What did not change between two ``show`` calls is reused through ``cache.py`` (the
precompute of unchanged lights and media, the world light when only a light changed);
the caller turns a depsgraph update into a new scene description (blender/viewport.py).
"""
from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Tuple

import numpy as np

from .scene import SceneDescription

COARSE_SCALE = 4      # the coarse stage's pixels are this many viewport pixels on a side
COARSE_PATHS = 1 / 16 # the coarse stage's share of the scene's light paths
COARSE_LATTICE = 0.5  # and of its light pyramid's points along a side


@dataclass(frozen=True)
class Stage:
    """One picture of the progression.  ``scale``: viewport pixels per rendered pixel along
    each side (the image is ``ceil(W / scale)`` x ``ceil(H / scale)``); ``samples``: rays per
    pixel; ``paths``: the share of the scene's light paths (multiple scattering);
    ``any_camera``: the precompute may be an earlier camera position's (render.render);
    ``resolution``: the share of the light pyramid's lattice points along a side
    (``Settings.multiple_resolution``): fewer points, each gathering more of the paths;
    ``surface_cache``: the stage may gather the surfaces' light once on a grid
    (``Settings.surface_cache``, surfacecache.py), a fixed cost per frame that only a stage of
    several samples a pixel earns back."""

    scale: int = 1
    samples: int = 1
    paths: float = 1.0
    any_camera: bool = False
    resolution: float = 1.0
    surface_cache: bool = True


def stages(samples: int) -> List[Stage]:
    """The default progression for a viewport of ``samples`` samples per pixel: the coarse
    stage; the full resolution at 1 sample with the coarse stage's share of the paths (its
    precompute, already made for this view unless the view orbited); then the scene's own
    paths at 4, 16, ... samples, the last at ``samples``.  With 1 sample: the coarse stage
    and the F12 render.  The one-sample stages gather the surfaces' light per sample: the
    surface cache (a fixed cost per frame) would make them slower, not better."""
    out = [Stage(COARSE_SCALE, 1, COARSE_PATHS, True, COARSE_LATTICE, False)]
    n = 1
    while n < samples:
        out.append(Stage(1, n, COARSE_PATHS, False, COARSE_LATTICE, False) if n == 1
                   else Stage(1, n))
        n *= 4
    out.append(Stage(1, max(int(samples), 1)))
    return out


@dataclass
class ViewImage:
    """A finished stage.  ``rgba``: float32 (h, w, 4), row 0 at the top, scene-linear,
    ``h``/``w`` the stage's size (draw it stretched over the viewport); ``stage``: its index
    in the progression and ``last`` whether no stage follows; ``seconds``: from the ``show``
    call that asked for it to its end; ``generation``: which ``show`` it answers;
    ``stats``/``timings``/``warnings``: the render's (render.RenderOutput)."""

    rgba: np.ndarray
    stage: int
    last: bool
    seconds: float
    generation: int
    stats: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)


def stage_scene(desc: SceneDescription, stage: Stage) -> SceneDescription:
    """``desc`` as ``stage`` renders it: the image ``scale`` times smaller along each side
    (the same view plane), ``samples`` per pixel and its share of the light paths.  Only the
    film's pixel counts change, so the precompute is the full-size picture's."""
    cam, st = desc.camera, desc.settings
    w = max(1, -(-int(cam.width) // stage.scale))
    h = max(1, -(-int(cam.height) // stage.scale))
    paths = st.multiple_paths
    if stage.paths < 1.0 and paths > 0:
        paths = int(round(paths * stage.paths))   # 0: the walk (walk.py) instead of paths
    return dataclasses.replace(
        desc, camera=dataclasses.replace(cam, width=w, height=h),
        settings=dataclasses.replace(
            st, samples=int(stage.samples), multiple_paths=paths,
            surface_cache=bool(st.surface_cache and stage.surface_cache),
            multiple_resolution=max(8, int(round(st.multiple_resolution * stage.resolution)))))


class Progressive:
    """Renders the latest scene handed to ``show`` in ``stages`` on a worker thread.

    ``render_fn(desc, should_cancel=..., any_camera=...)`` renders one frame
    (render.render); ``stages_fn(desc)`` gives the progression of a scene (default:
    ``stages(desc.settings.samples)``).  ``on_image(image)`` (optional) is called on the
    worker thread after each finished stage.  ``close()`` stops the thread."""

    def __init__(self, render_fn: Optional[Callable] = None,
                 stages_fn: Optional[Callable[[SceneDescription], List[Stage]]] = None,
                 on_image: Optional[Callable[[ViewImage], None]] = None):
        if render_fn is None:
            from .render import render as render_fn
        self._render = render_fn
        self._stages = stages_fn or (lambda d: stages(d.settings.samples))
        self._on_image = on_image
        self._lock = threading.Condition()
        self._job: Optional[Tuple[int, SceneDescription, float]] = None
        self._generation = 0
        self._image: Optional[ViewImage] = None
        self._busy = False
        self._failed = 0       # the last generation whose render raised
        self._closed = False
        self.errors: List[str] = []
        self._thread = threading.Thread(target=self._run, name="mpp-viewport", daemon=True)
        self._thread.start()

    # -- the caller's side ------------------------------------------------------------------

    def show(self, desc: SceneDescription) -> int:
        """Render ``desc`` from the first stage on, abandoning the work under way; returns
        the new generation (``ViewImage.generation`` of its pictures)."""
        with self._lock:
            self._generation += 1
            self._job = (self._generation, desc, time.perf_counter())
            self._busy = True
            self._lock.notify_all()
            return self._generation

    def latest(self) -> Optional[ViewImage]:
        """The newest finished picture (possibly of an earlier generation), or None."""
        with self._lock:
            return self._image

    @property
    def busy(self) -> bool:
        """True while a stage of the current generation is still to come."""
        with self._lock:
            return self._busy

    def wait(self, generation: int, stage: Optional[int] = None,
             timeout: float = 60.0) -> Optional[ViewImage]:
        """Block until ``generation`` has finished ``stage`` (None: its last); returns that
        picture, or None on timeout, when a newer ``show`` superseded it, or when its render
        raised (``errors``) (tests, benchmarks)."""
        deadline = time.perf_counter() + timeout
        with self._lock:
            while True:
                img = self._image
                if img is not None and img.generation == generation and \
                        (img.last if stage is None else img.stage >= stage):
                    return img
                if self._generation != generation or self._closed or \
                        self._failed == generation:
                    return None
                left = deadline - time.perf_counter()
                if left <= 0:
                    return None
                self._lock.wait(left)

    def close(self) -> None:
        """Stop the worker (the work under way is cancelled); idempotent."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=10.0)

    # -- the worker ---------------------------------------------------------------------------

    def _stale(self, generation: int) -> bool:
        return self._closed or self._generation != generation

    def _run(self) -> None:
        while True:
            with self._lock:
                while self._job is None and not self._closed:
                    self._lock.wait()
                if self._closed:
                    return
                generation, desc, asked = self._job
                self._job = None
            self._progress(generation, desc, asked)

    def _progress(self, generation: int, desc: SceneDescription, asked: float) -> None:
        """Render the stages of ``desc`` until they end or a newer generation comes."""
        def cancelled():
            return self._stale(generation)

        plan = self._stages(desc)
        for k, stage in enumerate(plan):
            if cancelled():
                return
            try:
                out = self._render(stage_scene(desc, stage), should_cancel=cancelled,
                                   any_camera=stage.any_camera)
            except Exception as e:  # say why in the viewport; keep the thread for the next change
                with self._lock:
                    self.errors.append(f"{type(e).__name__}: {e}")
                    self._failed = generation
                    if not self._stale(generation):
                        self._busy = False
                    self._lock.notify_all()
                return
            if out.cancelled or cancelled():
                return
            img = ViewImage(out.passes["Combined"], k, k == len(plan) - 1,
                            time.perf_counter() - asked, generation, dict(out.stats),
                            dict(out.timings), list(out.warnings))
            with self._lock:
                if self._stale(generation):
                    return
                self._image = img
                if img.last:
                    self._busy = False
                self._lock.notify_all()
            if self._on_image is not None:
                self._on_image(img)
