"""One frame's camera march, tile by tile (render.py prepares what it reads).

A tile is up to ``TILE_RAYS`` camera rays: ``samples`` jittered rays per pixel
(``pixel_offsets``; with depth of field each ray also leaves its own point of the lens),
their surface hits (surfaces.py), the march through the media (march.py) to the hit or the
clip end, the surfaces' shading with the volumes' light gathered onto them, and for the
world's fog its stretch beyond the fog's grid (worldfog.tail).  Radiance in W/(m^2 sr),
lengths in metres; each tile draws its random numbers from (seed, tile), so a frame is the
same bits however its tiles are shared among threads.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from . import kernels, worldfog
from .camera import primary_rays
from .march import MarchContext, march_rays, ray_keys
from .media import union_interval
from .passes import DEPTH_MISS
from .precompute.lightdepth import kernel_arrays, split_fog
from .surfaces import SurfaceSet, intersect, shade

GATHER_SEED = 0x5BD1E995  # offsets the seed of the rays that gather volume light onto surfaces
TILE_RAYS = 4096     # rays per tile at most: Esc and progress are served between tiles


def tile_size(samples: int, largest: int = 64) -> int:
    """Tile side (pixels) so that a tile holds at most TILE_RAYS rays (4 to ``largest``,
    Tuning.tile)."""
    return int(np.clip(int(math.sqrt(TILE_RAYS / max(1, samples))), 4, largest))


def pixel_offsets(samples: int, rng):
    """(samples, 2) jittered offsets in [0,1)^2: stratified on a k x k grid when samples is
    a square, otherwise uniform."""
    k = int(round(math.sqrt(samples)))
    if k * k == samples:
        g = np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2)
        return (g + rng.random((samples, 2))) / k
    return rng.random((samples, 2))


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

    def __post_init__(self):
        self.spp = max(1, int(self.st.samples))
        self.size = tile_size(self.spp, self.st.tuning.tile)
        W, H = int(self.cam.width), int(self.cam.height)
        self.tiles = [(x0, y0) for y0 in range(0, H, self.size) for x0 in range(0, W, self.size)]
        self.solid = split_fog(self.media)[0]
        self.arrays = kernel_arrays(self.solid)

    def optical_depth(self, p, d, t_max):
        """RGB optical depth (N,3) through the media from points ``p`` along ``d`` to
        ``t_max`` (the fog analytically): the surfaces' shadow rays."""
        tau = np.zeros((len(p), 3))
        if self.solid:
            t0, t1 = union_interval(self.solid, p, d, np.zeros(len(p)), t_max)
            tau = kernels.optical_depth(p, d, np.maximum(t1, 0.0), *self.arrays, self.step, 0.5)
        if self.fog_pm is not None:
            tau = tau + worldfog.optical_depth(self.fog_pm.sigma_t, t_max)
        return tau

    def radiance_towards(self, index):
        """``(points, dirs, t_max) -> (N,3)``: the radiance the volumes scatter and emit
        towards ``points`` along ``dirs`` (a march of tile ``index``'s own random stream):
        the light they throw onto a surface (surfaces.shade); None without media."""
        if self.ctx is None:
            return None

        def radiance(p, d, t_max):
            n = len(p)
            t0, t1 = union_interval(self.media, p, d, np.zeros(n), t_max)
            r = march_rays(self.ctx, p, d, t0, t1, np.ones(n),
                           ray_keys(self.st.seed + GATHER_SEED, index, n))
            return r["single"] + r["multiple"] + r["emission"]
        return radiance

    def rays(self, index, rng):
        """The tile's camera rays: (o, d, t_min, t_max, axial, (x0, y0, width, height))."""
        x0, y0 = self.tiles[index]
        tw = min(self.size, int(self.cam.width) - x0)
        th = min(self.size, int(self.cam.height) - y0)
        offs = pixel_offsets(self.spp, rng)
        yy, xx = np.mgrid[y0:y0 + th, x0:x0 + tw]
        px = (xx.reshape(-1, 1) + offs[None, :, 0]).ravel()
        py = (yy.reshape(-1, 1) + offs[None, :, 1]).ravel()
        lens = rng.random((len(px), 2)) if self.cam.aperture > 0.0 else None
        return primary_rays(self.cam, px, py, lens) + ((x0, y0, tw, th),)

    def tile(self, index):
        """(index, (x0, y0, width, height), passes of the tile (pixels, C), march samples)."""
        st, spp, fog_pm = self.st, self.spp, self.fog_pm
        rng = np.random.default_rng([st.seed, index])
        o, d, tmin, tmax, axial, box = self.rays(index, rng)
        n = len(o)
        t_hit, tri = intersect(self.surf, o, d, tmax)
        hit = tri >= 0
        # the world's fog reaches beyond the clip end on rays that hit nothing, as in Cycles
        t_end = np.where(hit, t_hit, np.inf) if fog_pm is not None else t_hit
        void = tmax < tmin   # a panoramic lens's points outside its circle: black
        t_end = np.where(void, tmin, t_end)
        if self.ctx is not None:
            t0, t1 = union_interval(self.media, o, d, tmin, t_end)
            r = march_rays(self.ctx, o, d, t0, t1, axial, ray_keys(st.seed, index, n))
        else:
            r = {"single": np.zeros((n, 3)), "T": np.ones((n, 3)), "depth": np.full(n, DEPTH_MISS),
                 "multiple": np.zeros((n, 3)), "steps": np.zeros(n), "emission": np.zeros((n, 3))}
        behind = np.broadcast_to(self.bg, (n, 3)).copy()
        behind[void] = 0.0
        if hit.any():
            # each pixel's samples gather through a Latin hypercube of directions
            bands = np.argsort(rng.random((2, n // spp, spp)), axis=2).reshape(2, n)
            ph = o[hit] + d[hit] * t_hit[hit, None]
            behind[hit] = shade(self.surf, tri[hit], ph, d[hit], self.lights, self.bg,
                                self.optical_depth, rng, self.radiance_towards(index),
                                gathers=st.tuning.surface_gathers,
                                strata=(bands[0][hit], bands[1][hit], spp))
            dh = t_hit[hit] * axial[hit]
            r["depth"][hit] = np.minimum(r["depth"][hit], dh)
        if fog_pm is not None:  # the homogeneous fog beyond its grid, seen through the march
            s0 = np.maximum(worldfog.tail_start(fog_pm, o, d), tmin)
            t_single, t_emit, t_trans, t_multi = worldfog.tail(self.fog, self.lights, o, d, s0,
                                                               t_end, far=self.far)
            r = dict(r, single=r["single"] + r["T"] * t_single,
                     multiple=r["multiple"] + r["T"] * t_multi,
                     emission=r["emission"] + r["T"] * t_emit, T=r["T"] * t_trans)
        return index, box, self.pixels(r, hit, behind, box[2] * box[3]), float(r["steps"].sum())

    def pixels(self, r, hit, behind, npx):
        """The passes of ``npx`` pixels from their rays' march ``r``, surface hits ``hit``
        and what lies behind the media ``behind`` (the box filter over each pixel)."""
        spp, out, st = self.spp, self.out, self.st

        def pixel_mean(a):  # (n, C) per ray -> (pixels, C)
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
        return res
