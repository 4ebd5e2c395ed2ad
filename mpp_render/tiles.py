"""One frame's camera march, tile by tile (render.py prepares what it reads).

A tile is up to ``tile_rays`` camera rays (as many as the pilot's march samples per ray
say make a tile's budget): ``samples`` jittered rays per pixel
(``pixel_offsets``; with depth of field each ray also leaves its own point of the lens),
their surface hits (surfaces.py), the march through the media (march.py) to the hit or the
clip end, the surfaces' shading with the volumes' light gathered onto them, and for the
world's fog its stretch beyond the fog's grid (worldfog.tail).  Radiance in W/(m^2 sr),
lengths in metres; each tile draws its random numbers from (seed, tile), so a frame is the
same bits however its tiles are shared among threads.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from . import kernels, pilot, worldfog
from .camera import primary_rays
from .march import MarchContext, march_rays, ray_keys, ray_keys_at
from .gathers import Guides
from .media import surrounds
from .passes import DEPTH_MISS
from .pixelsamples import PixelSamples, power_of_two_side, reverse_bits
from .precompute.lightdepth import kernel_arrays, media_bricks, split_fog
from .surfacecache import CACHE_SEED, CACHE_TILE, CHUNK_POINTS, Grid, SurfaceCache
from .surfaces import SurfaceSet, facing_normals, gathered, intersect, offset_points, shade

SAMPLES_SEED = 0x27D4EB2F  # offsets the seed of the tiles' pixel samples (pixelsamples.py)
GATHER_SEED = 0x5BD1E995  # offsets the seed of the rays that gather volume light onto surfaces
ROUND_SEED = 0x9E3779B1  # offsets the seed of each adaptive round's gathering rays
GATHER_TAIL_NODES = 4   # Gauss-Legendre points of the fog tail on a gather ray (worldfog.tail)


def tile_size(samples: float, largest: int, rays: int) -> int:
    """Tile side (pixels) so that a tile holds at most ``rays`` rays (tile_rays) at
    ``samples`` rays per pixel (with adaptive sampling, the pilot's expectation), 4 to
    ``largest`` (Tuning.tile).  Esc and progress are served between tiles."""
    return int(np.clip(int(math.sqrt(max(1, rays) / max(1.0, samples))), 4, largest))


def tile_rays(samples_per_ray: Optional[float], least: int, most: int, budget: float) -> int:
    """Camera rays a tile holds: as many as make ``budget`` march samples
    (Tuning.tile_samples) at ``samples_per_ray`` (the pilot's, its camera rays' and their
    surface gathers' together), within [``least``, ``most``] (Tuning.tile_rays,
    Tuning.tile_rays_most); ``least`` without a pilot (None).  Each tile's Python work is
    a cost per tile beside the kernels' per sample: where rays are cheap, larger tiles
    spread it; where they are dear, a tile stays short enough for Esc and the progress
    bar.  The pilot's counts are the same on every machine, so is the cut."""
    least, most = max(1, int(least)), max(1, int(least), int(most))
    if samples_per_ray is None:
        return least
    if not samples_per_ray > 0.0:   # nothing to march: rays as cheap as they come
        return most
    return int(np.clip(int(budget / samples_per_ray), least, most))


@dataclass
class FrameMarch:
    """What every tile of one frame reads: the settings ``st``, the camera ``cam``, the
    prepared ``media`` (the fog's grid among them as ``fog_pm``, the fog itself ``fog``), the
    surfaces ``surf``, the ``lights`` as the media see them, the background ``bg`` (RGB
    W/(m^2 sr)), the fog's far field ``far``, the march's context ``ctx`` (None without
    media), the step (m) of the shadow rays, and the passes ``out`` (their names)."""

    st: object
    cam: object
    media: list
    surf: SurfaceSet
    lights: list
    bg: np.ndarray
    fog: object
    fog_pm: object
    far: Optional[worldfog.FarField]
    ctx: Optional[MarchContext]
    step: float
    out: dict
    plan: Optional[pilot.SamplePlan] = None
    cache: Optional[SurfaceCache] = None

    def __post_init__(self):
        tun = self.st.tuning
        self.spp = max(1, int(self.st.samples))
        # the adaptive first round (at least 2: a variance needs two), never above spp
        self.first = min(self.spp, max(2, int(tun.adaptive_first)))
        W, H = int(self.cam.width), int(self.cam.height)
        self.cut(self.spp)
        self.solid = split_fog(self.media)[0]
        # the fog's own glow scattered beyond its grid (worldfog.glow_radiance)
        self.fog_glow = worldfog.glow_radiance(self.fog, bool(self.st.multiple)) \
            if self.fog is not None and worldfog.glows(self.fog) else None
        self.arrays = kernel_arrays(self.solid)
        # the shadow rays add the empty and constant bricks in one go (the same sum)
        self.bricks = media_bricks(self.solid, tun)
        # the lamps inside the media and the media that emit, towards which the surfaces'
        # gathers are also drawn
        self.guides = Guides.joined(
            Guides.of_lights(self.lights, lambda c: surrounds(self.media, c)),
            Guides.of_emitters(self.media)) if self.media else None
        self.pilot_stride = max(1, int(tun.pilot_stride))
        self.pilot_samples = max(2, int(tun.pilot_samples))
        self.pilot_shape, px, py = pilot.grid(W, H, self.pilot_stride)
        per = max(1, int(tun.tile_rays) // self.pilot_samples)   # the pilot's chunks
        self.pilot_pixels = [(px[i:i + per], py[i:i + per]) for i in range(0, len(px), per)]
        # the surfaces' gathered light on a grid over the image (surfacecache.py)
        self.cache_grid = Grid.over(W, H, min(int(tun.surface_cache), W + 1)) \
            if not self.surf.empty and self.st.surface_cache and int(tun.surface_cache) >= 2 \
            else None
        self.cache_pixels = self.cache_grid.pixels() if self.cache_grid is not None else None

    def cut(self, samples: float, samples_per_ray: Optional[float] = None) -> None:
        """Cut the frame into tiles (``self.tiles``, their corners; ``self.size``, their side)
        for ``samples`` rays per pixel (tile_size) of ``samples_per_ray`` march samples
        each (tile_rays; None: not known)."""
        W, H = int(self.cam.width), int(self.cam.height)
        tun = self.st.tuning
        rays = tile_rays(samples_per_ray, tun.tile_rays, tun.tile_rays_most, tun.tile_samples)
        self.size = tile_size(samples, tun.tile, rays)
        self.tiles = [(x0, y0) for y0 in range(0, H, self.size) for x0 in range(0, W, self.size)]

    def use_plan(self, plan: pilot.SamplePlan, samples_per_ray: Optional[float] = None) -> None:
        """Sample by the pilot's ``plan``, the tiles cut for the rays it expects a pixel to
        take (``plan.expected``; the outliers, unknown before the tiles, are not counted),
        each of ``samples_per_ray`` march samples (the pilot's, pilot_cost)."""
        self.plan = plan
        self.cut(plan.expected, samples_per_ray)

    @property
    def cache_chunks(self) -> int:
        """How many chunks the surface cache's gathers take (cache_chunk); 0 without one."""
        if self.cache_grid is None:
            return 0
        return -(-self.cache_grid.nx * self.cache_grid.ny // CHUNK_POINTS)

    def cache_chunk(self, j):
        """(j, grid points, their offset points, facing normals, surfaces, gathered light,
        march samples) of chunk ``j`` of the surface cache's grid points whose rays meet a
        surface (surfacecache.py): ``Tuning.surface_cache_gathers`` gathers each, on random
        streams of their own."""
        st, tun = self.st, self.st.tuning
        gx, gy = self.cache_pixels
        idx = np.arange(j * CHUNK_POINTS, min((j + 1) * CHUNK_POINTS, len(gx)))
        o, d, tmin, tmax, _ = primary_rays(self.cam, gx[idx], gy[idx], None)
        t_hit, tri = intersect(self.surf, o, d, tmax)
        at = np.flatnonzero((tri >= 0) & (tmax >= tmin))   # not a panoramic lens's void
        steps = []
        if not at.size:
            return j, idx[at], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), \
                np.zeros((0, 3)), 0.0
        nrm = facing_normals(self.surf, tri[at], d[at])
        po = offset_points(self.surf, o[at] + d[at] * t_hit[at, None], nrm)
        rng = np.random.default_rng([st.seed + CACHE_SEED, j])
        g = gathered(self.surf, po, nrm, self.lights, self.bg, self.optical_depth, rng,
                     self.radiance_towards(CACHE_TILE + j, 0, steps),
                     tun.surface_bounces,
                     tun.surface_cache_gathers, None, self.guides, tun.guided_gathers)
        return j, idx[at], po, nrm, self.surf.surface[tri[at]], g, float(sum(steps))

    def use_cache(self, chunks) -> None:
        """Read the surfaces' gathered light from the cache the ``chunks`` (cache_chunk's
        results, any order) fill."""
        cache = SurfaceCache.empty(self.cache_grid)
        for c in chunks:
            cache.fill(*c[1:6])
        cache.smooth(self.st.tuning.surface_cache_smooth)
        self.cache = cache

    @property
    def wants_pilot(self) -> bool:
        """Adaptive sampling with more than one sample a pixel: the pilot plans it (not
        with ``Tuning.pilot_samples`` 0: every pixel's first round, Cycles' unit)."""
        return (self.st.noise_threshold > 0.0 and self.spp > 1
                and self.st.tuning.pilot_samples > 0)

    def pilot_chunk(self, j):
        """(j, sums of the luminance, of its square, samples, march samples, the surface
        gathers' march samples) of chunk ``j`` of the pilot's pixels (pilot.py), each with
        ``Tuning.pilot_samples`` samples.  Its random streams are its own: the frame's tiles
        do not depend on it, their cut only through its counts (pilot_cost)."""
        st, ns = self.st, self.pilot_samples
        px, py = self.pilot_pixels[j]
        n = len(px)
        index = pilot.PILOT_TILE + j          # a stream of its own, apart from the tiles'
        rng = np.random.default_rng([st.seed + pilot.PILOT_SEED, j])
        offs = pilot.offsets(ns, n, rng)
        lens = rng.random((n * ns, 2)) if self.cam.aperture > 0.0 else None
        o, d, tmin, tmax, axial = primary_rays(self.cam, (px[:, None] + offs[..., 0]).ravel(),
                                               (py[:, None] + offs[..., 1]).ravel(), lens)
        bands = np.argsort(rng.random((2, n, ns)), axis=2)
        keys = ray_keys(st.seed + pilot.PILOT_SEED, index, n * ns)
        gathered_steps = []
        r, hit, behind = self.march(index, 0, rng, o, d, tmin, tmax, axial, keys,
                                    (bands[0].ravel(), bands[1].ravel(), ns), gathered_steps,
                                    (px[:, None] + offs[..., 0]).ravel(),
                                    (py[:, None] + offs[..., 1]).ravel())
        acc = Accumulator(n, {})
        acc.add(np.arange(n), ns, r, hit, behind, st.film_transparent)
        return (j, acc.lum, acc.lum2, acc.count, float(r["steps"].sum()),
                float(sum(gathered_steps)))

    @staticmethod
    def pilot_cost(chunks) -> float:
        """March samples per camera ray in the pilot's ``chunks`` (pilot_chunk's results),
        their surface gathers' counted in: what a tile's ray costs (tile_rays).  Summed in
        the chunks' order, not the order the threads finished them in."""
        chunks = sorted(chunks, key=lambda c: c[0])
        rays = sum(float(c[3].sum()) for c in chunks)
        return sum(c[4] + c[5] for c in chunks) / rays if rays > 0 else 0.0

    def make_plan(self, chunks) -> pilot.SamplePlan:
        """The frame's SamplePlan from every pilot_chunk's result (any order)."""
        chunks = sorted(chunks, key=lambda c: c[0])
        lum, lum2, count = (np.concatenate([c[i] for c in chunks]) for i in (1, 2, 3))
        return pilot.plan(lum, lum2, count, self.pilot_shape, self.st.noise_threshold,
                          self.pilot_stride, int(self.cam.width), int(self.cam.height),
                          self.spp, self.first)

    def optical_depth(self, p, d, t_max):
        """RGB optical depth (N,3) through the media from points ``p`` along ``d`` to
        ``t_max`` (the fog analytically): the surfaces' shadow rays."""
        tau = np.zeros((len(p), 3))
        if self.solid:
            t0, t1 = kernels.union_interval(self.solid, p, d, np.zeros(len(p)), t_max)
            tau = kernels.optical_depth(p, d, np.maximum(t1, 0.0), *self.arrays, self.step, 0.5,
                                        bricks=self.bricks)
        if self.fog_pm is not None:
            tau = tau + worldfog.optical_depth(self.fog_pm.sigma_t, t_max)
        return tau

    def radiance_towards(self, index, k=0, steps: Optional[list] = None):
        """``(points, dirs, t_max) -> ((N,3), (N,3))``: the radiance the volumes scatter and
        emit towards ``points`` along ``dirs`` (a march of tile ``index``'s own random
        stream, of its round ``k``), the light they throw onto a surface, and the same
        march's transmittance to ``t_max`` (the fog beyond its grid included), through which
        the surface sees the sky or another surface (surfaces.shade); None without media.
        Each march's samples are appended to ``steps`` where given."""
        if self.ctx is None:
            return None
        ctx = self.ctx.for_gathers()

        def radiance(p, d, t_max):
            n = len(p)
            t0, t1 = kernels.union_interval(self.media, p, d, np.zeros(n), t_max)
            r = march_rays(ctx, p, d, t0, t1, np.ones(n),
                           ray_keys(self.st.seed + GATHER_SEED + ROUND_SEED * k, index, n))
            if steps is not None:
                steps.append(float(r["steps"].sum()))
            r = self.fog_tail(r, p, d, np.zeros(n), t_max, nodes=GATHER_TAIL_NODES)
            return r["single"] + r["multiple"] + r["emission"], r["T"]
        return radiance

    def fog_tail(self, r, o, d, tmin, t_end, nodes: int = worldfog.TAIL_NODES):
        """The march's results ``r`` for rays o + t d with the world fog beyond its grid
        added, from where the grid's tail starts (not before ``tmin``) to ``t_end``, seen
        through the march (worldfog.tail); ``r`` as it is without a world fog."""
        if self.fog_pm is None:
            return r
        s0 = np.maximum(worldfog.tail_start(self.fog_pm, o, d), tmin)
        t_single, t_emit, t_trans, t_multi = worldfog.tail(self.fog, self.lights, o, d, s0,
                                                           t_end, nodes=nodes, far=self.far,
                                                           glow=self.fog_glow,
                                                           trilinear=kernels.trilinear,
                                                           light_sample=kernels.light_sample)
        return dict(r, single=r["single"] + r["T"] * t_single,
                    multiple=r["multiple"] + r["T"] * t_multi,
                    emission=r["emission"] + r["T"] * t_emit, T=r["T"] * t_trans)

    def tile(self, index):
        """(index, (x0, y0, width, height), passes of the tile (pixels, C), (march samples,
        camera samples)).

        Each pixel has ``samples`` samples whose offsets in the pixel, lens points, random
        keys, surface-gather bands and strata of the march's steps (with the pixel's key
        that shuffles them per step) are counter-based draws of (tile, pixel, sample)
        (pixelsamples.py), so a sample is the same whichever round takes it, and only the
        samples taken are drawn.  Adaptive sampling (``Settings.noise_threshold`` > 0): with the
        pilot's ``plan`` (pilot.py) every pixel first takes one sample, and the pixels the
        plan marks, the outliers (pilot.outliers) and their neighbours take the rest of
        ``Tuning.adaptive_first``; without a plan every pixel
        first takes ``Tuning.adaptive_first``.  Then rounds each doubling a pixel's samples
        (up to ``samples``) go to the pixels whose noise (pilot.relative_noise, in units of
        the plan's scale, 1 without one) is above the threshold, and their neighbours
        (noisy_pixels).  The rounds take each pixel's samples in ``sample_order`` (spread
        over the pixel).  With the threshold 0, or no more samples than the first round
        takes, one round of all the samples, drawn as without adaptive sampling."""
        st, spp = self.st, self.spp
        # the surfaces' own draws (surfaces.shade); without surfaces nothing draws from it
        rng = np.random.default_rng([st.seed, index]) if not self.surf.empty else None
        x0, y0 = self.tiles[index]
        tw = min(self.size, int(self.cam.width) - x0)
        th = min(self.size, int(self.cam.height) - y0)
        npx = tw * th
        yy, xx = np.mgrid[y0:y0 + th, x0:x0 + tw]
        yy, xx = yy.ravel(), xx.ravel()
        plan, first = self.plan, self.first   # a plan only where wants_pilot: spp > 1
        # no round to add when the first holds every sample: the plain draw, as threshold 0
        adaptive = st.noise_threshold > 0.0 and (spp > first or plan is not None)
        order = sample_order(spp) if adaptive else np.arange(spp)
        # each sample's offset, lens point, gather bands and key, drawn for the samples taken
        draws = PixelSamples(spp, npx, int(ray_keys(st.seed + SAMPLES_SEED, index, 1)[0]),
                             order if adaptive else None)
        lensed, hits_surfaces = self.cam.aperture > 0.0, not self.surf.empty
        taken = (1 if plan is not None else first) if adaptive else spp
        scale = plan.scale if plan is not None else 1.0
        more = plan.more[y0:y0 + th, x0:x0 + tw].ravel() if plan is not None else None
        acc = Accumulator(npx, self.out, spp if adaptive else 0)
        active, batch, k, steps = np.arange(npx), order[:taken], 0, 0.0
        while True:
            offs = draws.offsets(active, batch)
            px = (xx[active, None] + offs[..., 0]).ravel()
            py = (yy[active, None] + offs[..., 1]).ravel()
            ln = draws.lens(active, batch).reshape(-1, 2) if lensed else None
            o, d, tmin, tmax, axial = primary_rays(self.cam, px, py, ln)
            strata = None
            if hits_surfaces:
                bands = draws.bands(active, batch)
                strata = (bands[0].ravel(), bands[1].ravel(), spp)
            ids = (active[:, None] * spp + batch[None, :]).ravel()
            jitter = (draws.step_bands(active, batch).ravel(), spp,
                      np.repeat(draws.pixel_keys(active), len(batch)))
            r, hit, behind = self.march(index, k, rng, o, d, tmin, tmax, axial,
                                        ray_keys_at(st.seed, index, ids), strata, None, px, py,
                                        jitter)
            acc.add(active, len(batch), r, hit, behind, st.film_transparent,
                    taken - len(batch))
            steps += float(r["steps"].sum())
            if taken >= spp:
                break
            if taken < first:   # the plan's pixels and the outliers take the first round
                odd = pilot.grow(pilot.outliers(acc.lum, tw, th, scale,
                                                st.noise_threshold).reshape(th, tw)).ravel()
                active, upto = active[more[active] | odd[active]], first
            else:
                active = noisy_pixels(acc, active, st.noise_threshold, tw, th, scale)
                upto = min(spp, 2 * taken)
            if not len(active):
                break
            batch = order[taken:upto]
            taken += len(batch)
            k += 1
        return (index, (x0, y0, tw, th), acc.passes(st.film_transparent),
                (steps, float(acc.count.sum())))

    def march(self, index, k, rng, o, d, tmin, tmax, axial, keys, strata, gathered=None,
              px=None, py=None, jitter=None):
        """Round ``k`` of tile ``index``: the rays' march through the media (random
        ``keys``), their surface hits (gathering through the Latin hypercube ``strata``, or
        reading the surface cache at the rays' pixel positions ``px``, ``py``) and
        what lies behind the media: (the march's per-ray results, hit, behind).  The
        gathers' march samples are appended to ``gathered`` where given; ``jitter``: the
        rays' strata of their march steps (march.march_rays), or None."""
        st, fog_pm = self.st, self.fog_pm
        n = len(o)
        t_hit, tri = intersect(self.surf, o, d, tmax)
        hit = tri >= 0
        # the world's fog reaches beyond the clip end on rays that hit nothing, as in Cycles
        t_end = np.where(hit, t_hit, np.inf) if fog_pm is not None else t_hit
        void = tmax < tmin   # a panoramic lens's points outside its circle: black
        t_end = np.where(void, tmin, t_end)
        if self.ctx is not None:
            t0, t1 = kernels.union_interval(self.media, o, d, tmin, t_end)
            r = march_rays(self.ctx, o, d, t0, t1, axial, keys, jitter)
        else:
            r = {"single": np.zeros((n, 3)), "T": np.ones((n, 3)), "depth": np.full(n, DEPTH_MISS),
                 "multiple": np.zeros((n, 3)), "steps": np.zeros(n), "emission": np.zeros((n, 3))}
        behind = np.broadcast_to(self.bg, (n, 3)).copy()
        behind[void] = 0.0
        if hit.any():
            # each pixel's samples gather through a Latin hypercube of directions
            ph = o[hit] + d[hit] * t_hit[hit, None]
            cached = None
            if self.cache is not None and px is not None:
                hx, hy = np.asarray(px)[hit], np.asarray(py)[hit]
                cache, owner = self.cache, self.surf.surface

                def cached(po, nrm, tri_at):
                    return cache.lookup(hx, hy, po, nrm, owner[tri_at])
            behind[hit] = shade(self.surf, tri[hit], ph, d[hit], self.lights, self.bg,
                                self.optical_depth, rng, self.radiance_towards(index, k, gathered),
                                bounces=st.tuning.surface_bounces,
                                gathers=st.tuning.surface_gathers,
                                strata=(strata[0][hit], strata[1][hit], strata[2]),
                                guides=self.guides, guided=st.tuning.guided_gathers,
                                cached=cached)
            dh = t_hit[hit] * axial[hit]
            r["depth"][hit] = np.minimum(r["depth"][hit], dh)
        # the homogeneous fog beyond its grid, seen through the march
        return self.fog_tail(r, o, d, tmin, t_end), hit, behind


def noisy_pixels(acc, active, threshold: float, tw: int, th: int,
                 scale: float = 1.0) -> np.ndarray:
    """The pixels of ``active`` (indices into a ``tw`` x ``th`` tile, row-major) that take
    more samples: those whose noise (Accumulator.noise in units of ``scale``) is above
    ``threshold`` and their active neighbours
    (3 x 3), as Cycles widens its adaptive sampling's active area: a pixel whose first
    samples happen to agree does not stop beside noisy ones."""
    noisy = np.zeros((th, tw), bool)
    keep = np.zeros((th, tw), bool)
    noisy.flat[active[acc.noise(active, scale) > threshold]] = True
    keep.flat[active] = True
    return np.flatnonzero(pilot.grow(noisy) & keep)


@functools.lru_cache(maxsize=16)
def sample_order(spp: int) -> np.ndarray:
    """The order in which adaptive rounds take a pixel's ``spp`` samples: for a k x k grid
    of strata (PixelSamples.offsets) with k a power of two, by the bit-reversed Morton code of the
    stratum, so that the first 4^m samples hold one sample in each cell of a 2^m x 2^m grid
    over the pixel; otherwise in their own order.  Read-only (every tile shares it)."""
    order = _sample_order(spp)
    order.flags.writeable = False
    return order


def _sample_order(spp: int) -> np.ndarray:
    k = power_of_two_side(spp)
    if not k:
        return np.arange(spp)
    bits = k.bit_length() - 1
    i, j = np.divmod(np.arange(spp), k)
    morton = np.zeros(spp, np.int64)          # ... i_b j_b ... i_0 j_0
    for b in range(bits):
        morton |= ((j >> b) & 1) << (2 * b)
        morton |= ((i >> b) & 1) << (2 * b + 1)
    return np.argsort(reverse_bits(morton, 2 * bits), kind="stable")


class Accumulator:
    """A tile's per-pixel sums over the rounds of its samples (the box filter over each
    pixel), the passes ``out`` names: radiance W/(m^2 sr), transmittance, depth (m).

    With ``samples`` (the most a pixel takes), each sample's luminance is kept by the
    place it was taken in (``taken``), for ``noise``'s halves."""

    # the sums' columns: single, multiple, emission, T, behind (RGB each), open
    COLUMNS = {"single": slice(0, 3), "multiple": slice(3, 6), "emission": slice(6, 9),
               "T": slice(9, 12), "behind": slice(12, 15), "open": 15}

    def __init__(self, npx: int, out: dict, samples: int = 0):
        self.out = out
        self.taken = np.zeros((npx, samples)) if samples > 0 else None
        self.count = np.zeros(npx)
        self.total = np.zeros((npx, 16))
        self.sums = {key: self.total[:, col] for key, col in self.COLUMNS.items()}
        self.lum = np.zeros(npx)       # sums of each sample's mean RGB radiance and its square
        self.lum2 = np.zeros(npx)
        self.depth = np.full(npx, np.inf)

    def add(self, pixels, spp, r, hit, behind, transparent: bool, start: int = 0) -> None:
        """Add ``spp`` samples of each of ``pixels`` (rays pixel-major): the march ``r``,
        surface hits ``hit``, what lies behind the media ``behind``; they are the pixels'
        samples taken ``start`` to ``start + spp - 1``."""
        n = len(pixels)
        vals = np.empty((n * spp, 18))
        vals[:, 0:3], vals[:, 3:6], vals[:, 6:9] = r["single"], r["multiple"], r["emission"]
        vals[:, 9:12] = r["T"]
        seen = vals[:, 12:15]
        np.multiply(r["T"], np.where(hit[:, None], behind, 0.0) if transparent else behind,
                    out=seen)
        vals[:, 15] = np.where(hit, 0.0, r["T"].mean(axis=1)) if transparent else 0.0
        lum = vals[:, 16]
        np.sum(vals[:, 0:9], axis=1, out=lum)
        lum += seen.sum(axis=1)
        lum /= 3.0
        vals[:, 17] = lum * lum
        tot = vals if spp == 1 else vals.reshape(n, spp, 18).sum(axis=1)
        self.total[pixels] += tot[:, :16]
        self.lum[pixels] += tot[:, 16]
        self.lum2[pixels] += tot[:, 17]
        if self.taken is not None:
            self.taken[pixels, start:start + spp] = lum.reshape(n, spp)
        self.count[pixels] += spp
        dep = np.where(r["depth"] < DEPTH_MISS, r["depth"], np.inf).reshape(n, spp).min(axis=1)
        self.depth[pixels] = np.minimum(self.depth[pixels], dep)

    def noise(self, pixels, scale: float = 1.0) -> np.ndarray:
        """The standard error of each pixel's mean luminance over sqrt((mean + 1e-4 S) S),
        S = ``scale`` the frame's mean luminance (pilot.relative_noise; with S = 1 Cycles'
        adaptive sampling's unit, sqrt(mean + 1e-4)), times sqrt(pilot.stratified_gain) of
        the pixels' samples as taken (where they are kept): their variance, read as that of
        independent samples, over what the halves of each pixel's samples show."""
        rel = pilot.relative_noise(self.lum[pixels], self.lum2[pixels], self.count[pixels],
                                   scale)
        if self.taken is None:
            return rel
        n = int(self.count[pixels].max()) if len(pixels) else 0
        if n < 2 or not np.all(self.count[pixels] == n):
            return rel
        gain = pilot.stratified_gain(self.taken[pixels, :n])
        return rel * math.sqrt(gain)

    def passes(self, transparent: bool) -> dict:
        """The passes the frame holds, each pixel the mean of its samples."""
        n = self.count[:, None]
        single, multi, emitted = (self.sums[k] / n for k in ("single", "multiple", "emission"))
        res = {}
        for name, val in (("Volume Single", single), ("Volume Multiple", multi),
                          ("Emission", emitted)):
            if name in self.out:
                res[name] = val
        if "Transmittance" in self.out:
            res["Transmittance"] = self.sums["T"] / n
        comb = np.empty((len(self.count), 4))
        comb[:, :3] = single + multi + emitted + self.sums["behind"] / n
        comb[:, 3] = 1.0 - self.sums["open"] / self.count if transparent else 1.0
        res["Combined"] = comb
        if "Depth" in self.out:
            res["Depth"] = np.where(np.isfinite(self.depth), self.depth, DEPTH_MISS)[:, None]
        return res
