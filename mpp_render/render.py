"""The render pipeline: scene description -> per-light precompute -> march -> passes.

The image is cut into square tiles; each tile's rays (``samples`` jittered rays per pixel,
stratified over the pixel square like Cycles' 1 px box filter) are marched independently with
a random stream seeded by (seed, tile index), so the image does not depend on the number of
threads.  ``progress`` and ``should_cancel`` are served between tiles.

A world volume (``World.volume``) becomes one more medium, a grid over the view frustum
(worldfog.py); rays leaving that grid get the fog beyond it from ``worldfog.tail``, and the
background and suns are dark in the fog's colour channels.
"""
from __future__ import annotations

import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import numpy as np

from . import cache, kernels, worldfog
from .blasthreads import one_blas_thread
from .march import MarchContext
from .lights import is_dark
from .media import prepare, smooth_light
from .cancel import Cancelled
from .parallel import worker_count
from .passes import DEPTH_MISS, enabled_passes
from .scene import SceneDescription
from .surfaces import prepare_surfaces
from .tiles import FrameMarch

@dataclass
class RenderOutput:
    """``passes``: name -> float32 (height, width, channels), row 0 at the top.
    ``timings``: seconds per stage ('precompute', 'march').  ``warnings``: messages for the
    user.  ``cancelled``: True when ``should_cancel`` stopped the render early (the passes
    then hold what was finished, zeros elsewhere)."""

    passes: Dict[str, np.ndarray]
    timings: Dict[str, float] = field(default_factory=dict)
    warnings: List[str] = field(default_factory=list)
    cancelled: bool = False
    stats: dict = field(default_factory=dict)


def auto_step(desc: SceneDescription, media, lights=()) -> float:
    """The march step (m): the user's Step Size, or of the finest voxel
    ``Tuning.smooth_step_voxels`` where the light in the media changes no faster than their
    voxels (media.smooth_light: density grids, no lamp within ``Tuning.disc_voxels`` voxels
    of them, no spot), but no longer than ``Tuning.smooth_step_tau`` of optical depth in the
    densest voxel, and ``Tuning.step_voxels`` elsewhere."""
    if desc.settings.step_size > 0:
        return float(desc.settings.step_size)
    if not media:
        return 1.0
    tun = desc.settings.tuning
    finest = min(pm.voxel_size for pm in media)
    step = tun.step_voxels * finest
    if smooth_light(media, [lt for lt in lights if not is_dark(lt)], tun.disc_voxels * finest):
        # no longer than the densest voxel's optical depth allows (Tuning.smooth_step_tau)
        densest = max(float(pm.grid.max()) * float(np.max(pm.sigma_t)) for pm in media)
        longest = tun.smooth_step_tau / densest if densest > 0.0 else np.inf
        step = max(step, min(tun.smooth_step_voxels * finest, longest))
    return step


def render(desc: SceneDescription,
           progress: Optional[Callable[[float, str], None]] = None,
           should_cancel: Optional[Callable[[], bool]] = None,
           any_camera: bool = False) -> RenderOutput:
    """Render one frame.  ``progress(fraction, message)`` is called between tiles;
    ``should_cancel()`` is polled between tiles and precompute chunks (Esc).  ``any_camera``:
    the precompute may be one kept for another camera position of the same scene
    (cache.precompute_cached; the viewport's coarse picture while orbiting).  numpy's BLAS
    runs on one thread meanwhile (blasthreads): the render's own pool fills the cores."""
    with one_blas_thread():
        return _render(desc, progress, should_cancel, any_camera)


def _render(desc, progress, should_cancel, any_camera) -> RenderOutput:
    """render()'s frame, with BLAS already on one thread."""
    st = desc.settings
    cam = desc.camera
    W, H = int(cam.width), int(cam.height)
    warnings = list(desc.warnings)
    notice = kernels.fallback_notice()
    if notice:
        warnings.append(notice)
    from .budget import apply_budget  # large grids are downsampled to fit the memory budget
    desc = apply_budget(desc, warnings)
    timings = {}
    media = prepare_media(desc.media, warnings)
    passes_on = [p.name for p in enabled_passes(st.multiple, st.passes)]
    out = {p.name: np.zeros((H, W, p.channels), np.float32) for p in enabled_passes(st.multiple, st.passes)}
    if "Depth" in out:
        out["Depth"][:] = DEPTH_MISS
    cancel = should_cancel or (lambda: False)

    surf = prepare_surfaces(desc.surfaces)
    fog = worldfog.active(desc.world)
    world, lights, fog_pm = with_world_fog(desc, fog, media, warnings)
    t_pre = time.perf_counter()
    step = auto_step(desc, media, lights)
    try:
        pre, media_lights = precompute_frame(desc, media, lights, world, surf, fog_pm, step,
                                             cancel, progress, any_camera)
    except Cancelled:
        return RenderOutput(out, {"precompute": time.perf_counter() - t_pre}, warnings, True)
    timings["precompute"] = time.perf_counter() - t_pre

    far = None   # the fog's multiply scattered light beyond its grid, for the tail
    if pre is not None and st.multiple and pre.multiple and fog_pm is not None:
        far = worldfog.far_field(pre.multiple[[m is fog_pm for m in media].index(True)])
    ctx = MarchContext(media, pre.fields if pre else [], pre.layout if pre else None,
                       media_lights, step, pre.multiple if st.multiple else None,
                       cam, st.tuning,
                       glow_moments=pre.glow_moments if pre and st.multiple else None) \
        if media else None
    frame = FrameMarch(st, cam, media, surf, lights, np.asarray(world.color, np.float64), fog,
                       fog_pm, far, ctx, step, out)
    t_march = time.perf_counter()
    threads = worker_count(st.threads)
    before_tiles = 0.0   # march samples of the surface cache and the pilot
    if frame.cache_chunks:
        chunks = run_chunks(frame.cache_chunk, frame.cache_chunks, threads, cancel, progress,
                            "Surface light")
        timings["surface_cache"] = time.perf_counter() - t_march
        if chunks is None:
            return RenderOutput(out, timings, warnings, True)
        frame.use_cache(chunks)
        before_tiles += sum(c[6] for c in chunks)
    if frame.wants_pilot:
        chunks = run_chunks(frame.pilot_chunk, len(frame.pilot_pixels), threads, cancel,
                            progress, "Pilot")
        timings["pilot"] = time.perf_counter() - t_march
        if chunks is None:
            return RenderOutput(out, timings, warnings, True)
        frame.use_plan(frame.make_plan(chunks), frame.pilot_cost(chunks))
        before_tiles += sum(c[4] for c in chunks)
    (march_samples, camera_samples), cancelled = march_tiles(frame.tile, len(frame.tiles),
                                                             threads, cancel, progress, out)
    timings["march"] = time.perf_counter() - t_march
    stats = {"backend": kernels.backend(), "step": step, "tiles": len(frame.tiles),
             "passes": passes_on,
             "march_samples": march_samples + before_tiles, "threads": threads,
             "pixel_samples": camera_samples / max(W * H, 1)}
    if pre is not None:
        stats.update(pre.stats)
    return RenderOutput(out, timings, warnings, cancelled, stats)


def prepare_media(media, warnings: List[str]) -> list:
    """The scene's media prepared for the precompute and the march (media.prepare); one that
    cannot be is left out with its reason in ``warnings``."""
    out = []
    for m in media:
        try:
            out.append(prepare(m, warnings))
        except ValueError as e:
            warnings.append(str(e))
    return out


def precompute_frame(desc: SceneDescription, media, lights, world, surf, fog_pm, step, cancel,
                     progress, any_camera: bool = False):
    """(Precomputed or None without media, the lights the media see): the precompute of the
    frame, reused from earlier renders where its inputs did not change (cache.py); with the
    walk the flat surfaces' bounce lights join the lights (bounce.py).  Raises Cancelled."""
    st = desc.settings
    media_lights = lights
    if media and st.multiple and st.surface_bounce and desc.surfaces and fog_pm is None \
            and st.multiple_paths <= 0:
        from .bounce import bounce_lights  # the walk's light from flat surfaces: indirect
        # light, on with multiple scattering (Cycles' volume_bounces = 0 leaves it out too);
        # traced paths start on the lit surfaces instead (precompute.pathstarts); not under
        # a world volume, whose grid spans the whole view: each bounce light would cost a
        # light's precompute over all of it (bounce.py)
        media_lights = list(lights) + bounce_lights(desc.surfaces, lights, media, step)
    if not media:
        return None, media_lights
    pre = cache.precompute_cached(media, media_lights, world, desc.camera,
                                  n_dirs=st.ambient_directions, seed=st.seed,
                                  should_cancel=cancel, progress=progress,
                                  surfaces=None if surf.empty else surf,
                                  threads=st.threads, multiple=st.multiple,
                                  multiple_resolution=st.multiple_resolution,
                                  multiple_paths=st.multiple_paths,
                                  surface_bounce=st.surface_bounce, tuning=st.tuning,
                                  any_camera=any_camera)
    return pre, media_lights


def with_world_fog(desc: SceneDescription, fog, media: list, warnings: List[str]):
    """(world, lights, the fog's PreparedMedium or None) as the media see them under the
    world's fog ``fog`` (worldfog.active; None: the scene's own): the fog's bounded medium
    is appended to ``media``, what it changes said in ``warnings``."""
    if fog is None:
        return desc.world, desc.lights, None
    world = worldfog.effective_world(desc.world, fog)
    lights = worldfog.effective_lights(desc.lights, fog)
    for before, after in zip(desc.lights, lights):
        if before.kind == "SUN" and np.any(np.asarray(before.strength) > 0) \
                and not np.any(np.asarray(after.strength) > 0):
            warnings.append(f"light '{before.name}': a sun lights nothing through the world "
                            "volume, which is endless (as in Cycles)")
    box = worldfog.bounded_medium(desc, fog, media, desc.settings.voxel_resolution)
    fog_pm = prepare(box.medium, warnings)
    media.append(fog_pm)
    if worldfog.infinite_emission(fog):
        warnings.append("world volume: it emits in a colour without extinction, which "
                        "is infinitely bright in Cycles; that emission beyond "
                        f"{box.depth:.3g} m is left out")
    if desc.settings.multiple and worldfog.lossless_glow(fog):
        warnings.append("world volume: it glows and scatters without absorbing in some "
                        "colour, where its light scattered again and again would be "
                        "infinitely bright (in Cycles as bright as Volume Bounces allow); "
                        "there its glow is scattered once")
    return world, lights, fog_pm


def run_chunks(work, n: int, threads: int, cancel, progress, label: str) -> Optional[list]:
    """``work(j)`` for j < ``n`` on a pool of ``threads`` threads (the surface cache's and
    the pilot's chunks), their results in order; None when Esc (``cancel()``, polled between
    chunks).  ``progress`` says "``label`` j/n"."""
    with ThreadPoolExecutor(max_workers=threads) as pool:
        futures = [pool.submit(work, j) for j in range(n)]
        chunks = []
        for j, f in enumerate(futures):
            if cancel():
                for g in futures:
                    g.cancel()
                return None
            chunks.append(f.result())
            if progress:
                progress(0.0, f"{label} {j + 1}/{n}")
    return chunks


def march_tiles(do_tile, n_tiles: int, threads: int, cancel, progress, out) -> tuple:
    """Run ``do_tile(index)`` for every tile on a pool of ``threads`` threads, at most two
    per thread queued, writing each result into the passes ``out`` as it comes; Esc
    (``cancel()``) is polled and ``progress`` told between tiles.  Returns ((march samples,
    camera samples), whether cancelled)."""
    done = 0
    march_samples = camera_samples = 0.0
    cancelled = False
    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = set()
        it = iter(range(n_tiles))
        for _ in range(threads * 2):
            i = next(it, None)
            if i is not None:
                pending.add(pool.submit(do_tile, i))
        while pending:
            # wait for whichever finishes first
            fin, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in fin:
                index, (x0, y0, tw, th), res, (n_steps, n_rays) = f.result()
                march_samples += n_steps
                camera_samples += n_rays
                for name, arr in res.items():
                    if name in out:
                        out[name][y0:y0 + th, x0:x0 + tw] = arr.reshape(th, tw, -1)
                done += 1
            if cancel():
                cancelled = True
                for f in pending:
                    f.cancel()
                break
            for _ in fin:
                i = next(it, None)
                if i is not None:
                    pending.add(pool.submit(do_tile, i))
            if progress:
                progress(done / n_tiles, f"Tiles {done}/{n_tiles}")
    return (march_samples, camera_samples), cancelled
