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

import math
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional

import numpy as np

from . import cache, kernels, worldfog
from .camera import primary_rays
from .march import MarchContext, march_rays, ray_keys
from .media import prepare, union_interval
from .parallel import Cancelled, worker_count
from .passes import DEPTH_MISS, enabled_passes
from .precompute.lightdepth import kernel_arrays, split_fog
from .scene import SceneDescription
from .surfaces import intersect, prepare_surfaces, shade

GATHER_SEED = 0x5BD1E995  # offsets the seed of the rays that gather volume light onto surfaces
TILE_RAYS = 4096     # rays per tile at most: Esc and progress are served between tiles


def tile_size(samples: int, largest: int = 64) -> int:
    """Tile side (pixels) so that a tile holds at most TILE_RAYS rays (4 to ``largest``,
    Tuning.tile)."""
    return int(np.clip(int(math.sqrt(TILE_RAYS / max(1, samples))), 4, largest))


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


def pixel_offsets(samples: int, rng):
    """(samples, 2) jittered offsets in [0,1)^2: stratified on a k x k grid when samples is
    a square, otherwise uniform."""
    k = int(round(math.sqrt(samples)))
    if k * k == samples:
        g = np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2)
        return (g + rng.random((samples, 2))) / k
    return rng.random((samples, 2))


def auto_step(desc: SceneDescription, media) -> float:
    """The march step (m): the user's, or half the finest voxel."""
    if desc.settings.step_size > 0:
        return float(desc.settings.step_size)
    return 0.5 * min(pm.voxel_size for pm in media) if media else 1.0


def render(desc: SceneDescription,
           progress: Optional[Callable[[float, str], None]] = None,
           should_cancel: Optional[Callable[[], bool]] = None) -> RenderOutput:
    """Render one frame.  ``progress(fraction, message)`` is called between tiles;
    ``should_cancel()`` is polled between tiles and precompute chunks (Esc)."""
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
    media = []
    for m in desc.media:
        try:
            media.append(prepare(m, warnings))
        except ValueError as e:
            warnings.append(str(e))
    passes_on = [p.name for p in enabled_passes(st.multiple, st.passes)]
    out = {p.name: np.zeros((H, W, p.channels), np.float32) for p in enabled_passes(st.multiple, st.passes)}
    if "Depth" in out:
        out["Depth"][:] = DEPTH_MISS
    cancel = should_cancel or (lambda: False)

    surf = prepare_surfaces(desc.surfaces)
    fog = worldfog.active(desc.world)
    world, lights, fog_pm = with_world_fog(desc, fog, media, warnings)
    t_pre = time.perf_counter()
    pre = None
    step = auto_step(desc, media)
    media_lights = lights
    if media and st.multiple and st.surface_bounce and desc.surfaces and fog_pm is None \
            and st.multiple_paths <= 0:
        from .bounce import bounce_lights  # the walk's light from flat surfaces: indirect
        # light, on with multiple scattering (Cycles' volume_bounces = 0 leaves it out too);
        # traced paths start on the lit surfaces instead (precompute.pathstarts); not under
        # a world volume, whose grid spans the whole view: each bounce light would cost a
        # light's precompute over all of it (bounce.py)
        media_lights = list(lights) + bounce_lights(desc.surfaces, lights, media, step)
    if media:
        # the light and world-light parts are reused from earlier renders when their inputs
        # did not change (cache.py)
        try:
            pre = cache.precompute_cached(media, media_lights, world, cam,
                                          n_dirs=st.ambient_directions, seed=st.seed,
                                          should_cancel=cancel, progress=progress,
                                          surfaces=None if surf.empty else surf,
                                          threads=st.threads, multiple=st.multiple,
                                          multiple_resolution=st.multiple_resolution,
                                          multiple_paths=st.multiple_paths,
                                          surface_bounce=st.surface_bounce,
                                          tuning=st.tuning)
        except Cancelled:
            return RenderOutput(out, {"precompute": time.perf_counter() - t_pre}, warnings, True)
    timings["precompute"] = time.perf_counter() - t_pre

    bg = np.asarray(world.color, np.float64)
    far = None   # the fog's multiply scattered light beyond its grid, for the tail
    if pre is not None and st.multiple and pre.multiple and fog_pm is not None:
        far = worldfog.far_field(pre.multiple[[m is fog_pm for m in media].index(True)])
    ctx = MarchContext(media, pre.fields if pre else [], pre.layout if pre else None,
                       media_lights, step, pre.multiple if st.multiple else None,
                       cam, st.tuning) if media else None
    od = kernels.optical_depth
    step_light = step

    solid = split_fog(media)[0]
    arrays = kernel_arrays(solid)

    def media_optical_depth(p, d, t_max):
        tau = np.zeros((len(p), 3))
        if solid:
            t0, t1 = union_interval(solid, p, d, np.zeros(len(p)), t_max)
            tau = od(p, d, np.maximum(t1, 0.0), *arrays, step_light, 0.5)
        if fog_pm is not None:
            tau = tau + worldfog.optical_depth(fog_pm.sigma_t, t_max)
        return tau

    def media_radiance(index):
        """``(points, dirs, t_max) -> (N,3)``: the radiance the volumes scatter and emit
        towards ``points`` along ``dirs`` (a march of tile ``index``'s own random stream):
        the light they throw onto a surface (surfaces.shade)."""
        def radiance(p, d, t_max):
            n = len(p)
            t0, t1 = union_interval(media, p, d, np.zeros(n), t_max)
            r = march_rays(ctx, p, d, t0, t1, np.ones(n), ray_keys(st.seed + GATHER_SEED, index, n))
            return r["single"] + r["multiple"] + r["emission"]
        return radiance if ctx is not None else None

    spp = max(1, int(st.samples))
    ts = tile_size(spp, st.tuning.tile)
    tiles = [(x0, y0) for y0 in range(0, H, ts) for x0 in range(0, W, ts)]

    def do_tile(index):
        x0, y0 = tiles[index]
        tw, th = min(ts, W - x0), min(ts, H - y0)
        rng = np.random.default_rng([st.seed, index])
        offs = pixel_offsets(spp, rng)
        yy, xx = np.mgrid[y0:y0 + th, x0:x0 + tw]
        px = (xx.reshape(-1, 1) + offs[None, :, 0]).ravel()
        py = (yy.reshape(-1, 1) + offs[None, :, 1]).ravel()
        lens = rng.random((len(px), 2)) if cam.aperture > 0.0 else None
        o, d, tmin, tmax, axial = primary_rays(cam, px, py, lens)
        n = len(o)
        t_hit, tri = intersect(surf, o, d, tmax)
        hit = tri >= 0
        # the world's fog reaches beyond the clip end on rays that hit nothing, as in Cycles
        t_end = np.where(hit, t_hit, np.inf) if fog_pm is not None else t_hit
        void = tmax < tmin   # a panoramic lens's points outside its circle: black
        t_end = np.where(void, tmin, t_end)
        if ctx is not None:
            t0, t1 = union_interval(media, o, d, tmin, t_end)
            r = march_rays(ctx, o, d, t0, t1, axial, ray_keys(st.seed, index, n))
        else:
            r = {"single": np.zeros((n, 3)), "T": np.ones((n, 3)), "depth": np.full(n, DEPTH_MISS),
                 "multiple": np.zeros((n, 3)), "steps": np.zeros(n), "emission": np.zeros((n, 3))}
        behind = np.broadcast_to(bg, (n, 3)).copy()
        behind[void] = 0.0
        if hit.any():
            # each pixel's samples gather through a Latin hypercube of directions
            bands = np.argsort(rng.random((2, n // spp, spp)), axis=2).reshape(2, n)
            ph = o[hit] + d[hit] * t_hit[hit, None]
            behind[hit] = shade(surf, tri[hit], ph, d[hit], lights, bg,
                                media_optical_depth, rng, media_radiance(index),
                                gathers=st.tuning.surface_gathers,
                                strata=(bands[0][hit], bands[1][hit], spp))
            dh = t_hit[hit] * axial[hit]
            r["depth"][hit] = np.minimum(r["depth"][hit], dh)
        if fog_pm is not None:  # the homogeneous fog beyond its grid, seen through the march
            s0 = np.maximum(worldfog.tail_start(fog_pm, o, d), tmin)
            t_single, t_emit, t_trans, t_multi = worldfog.tail(fog, lights, o, d, s0, t_end,
                                                               far=far)
            r = dict(r, single=r["single"] + r["T"] * t_single,
                     multiple=r["multiple"] + r["T"] * t_multi,
                     emission=r["emission"] + r["T"] * t_emit, T=r["T"] * t_trans)
        npx = th * tw

        def pixel_mean(a):  # (n, C) per ray -> (pixels, C), the box filter over the pixel
            return a if spp == 1 else a.reshape(npx, spp, -1).mean(axis=1)

        res = {}
        single, multi, emitted = pixel_mean(r["single"]), pixel_mean(r["multiple"]), \
            pixel_mean(r["emission"])
        for name, val in (("Volume Single", single), ("Volume Multiple", multi),
                          ("Emission", emitted)):
            if name in out:
                res[name] = val
        if "Transmittance" in out:
            res["Transmittance"] = pixel_mean(r["T"])
        comb = np.empty((npx, 4))
        if st.film_transparent:
            comb[:, :3] = single + multi + emitted + pixel_mean(
                r["T"] * np.where(hit[:, None], behind, 0.0))
            comb[:, 3] = 1.0 - pixel_mean(np.where(hit[:, None], 0.0, r["T"])).mean(axis=1)
        else:
            comb[:, :3] = single + multi + emitted + pixel_mean(r["T"] * behind)
            comb[:, 3] = 1.0
        res["Combined"] = comb
        if "Depth" in out:
            dep = r["depth"].reshape(npx, spp)
            hitd = dep < DEPTH_MISS
            res["Depth"] = np.where(hitd.any(axis=1), np.where(hitd, dep, np.inf).min(axis=1),
                                    DEPTH_MISS)[:, None]
        return index, (x0, y0, tw, th), res, float(r["steps"].sum())

    t_march = time.perf_counter()
    threads = worker_count(st.threads)
    march_samples, cancelled = march_tiles(do_tile, len(tiles), threads, cancel, progress, out)
    timings["march"] = time.perf_counter() - t_march
    stats = {"backend": kernels.backend(), "step": step, "tiles": len(tiles), "passes": passes_on,
             "march_samples": march_samples, "threads": threads}
    if pre is not None:
        stats.update(pre.stats)
    return RenderOutput(out, timings, warnings, cancelled, stats)


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
    return world, lights, fog_pm


def march_tiles(do_tile, n_tiles: int, threads: int, cancel, progress, out) -> tuple:
    """Run ``do_tile(index)`` for every tile on a pool of ``threads`` threads, at most two
    per thread queued, writing each result into the passes ``out`` as it comes; Esc
    (``cancel()``) is polled and ``progress`` told between tiles.  Returns (march samples,
    whether cancelled)."""
    done = 0
    march_samples = 0.0
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
                index, (x0, y0, tw, th), res, n_steps = f.result()
                march_samples += n_steps
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
    return march_samples, cancelled
