"""The world fog's own glow scattered in the fog (docs/method.md, "The world fog's glow").

Cycles' world volume is an endless homogeneous medium; where it emits e (W/(m^3 sr)) and
scatters, every point of it is lit by the glow of all the rest.  Away from anything else the
answer is closed: the radiance is the same everywhere and in every direction,

    L = e / sigma_a  =  e / sigma_t  +  e sigma_s / (sigma_a sigma_t)      [W/(m^2 sr)]

(unscattered glow E1_inf, and glow that has scattered Em_inf: worldfog.glow_radiance).  What
the scene's surfaces change is the *deficit* D = L_inf - L.  It obeys the transport equation
without sources in the fog, and at a diffuse surface of albedo rho, where L_inf would leave
and rho / pi times the arriving light does,

    D_out = (1 - rho) e / sigma_a + rho / pi * integral D_in cos     (Lambertian),

so D is the light of the surfaces themselves glowing with radiance S = (1 - rho) e /
sigma_a and reflecting with their albedo: traced with the lamps' light paths (paths.py,
lobe 1), started on the front of the surfaces within the fog's reach (pathstarts.reach).
The unscattered glow alone (what Cycles scatters with Volume Bounces 0, whose paths end at
the first surface after a scattering) misses, beside a surface, what lies behind it: its
deficit D0 is the unscattered light of the surfaces glowing with e / sigma_t (cast from
each lattice point, ``surface_view``).  On the fog's lattice:

    E1 = E1_inf - D0                                     (Volume Single)
    Em = E1_inf + Em_inf - D - E1                        (Volume Multiple)

both at least 0, added to the fog's world channels as a glowing medium's are
(precompute.emissionlight).  Exact without surfaces; converges with the paths.  The other
media in the fog are lit by its glow as by a sky (``glow_on_medium``).  Left out: the other
media's shade on the fog's glow.  Where the fog absorbs nothing in a channel its multiply
scattered glow is infinite: only E1 there.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..parallel import run_chunks
from ..surfaces import intersect
from ..scene import Tuning, World
from ..worldfog import glow_radiance
from .lattice import lattice_points
from .lightdepth import density_lengths, extinction_media
from .lightpaths import PathLattice, _trace_all
from .pathstarts import (LIFT, SURFACE_POINTS, Surroundings, reach, surface_albedo,
                         surface_points)
from .worldlight import on_lattice, phase_directions, world_chunk, world_lattice, world_light

# the deficit's paths, a fraction of the Paths setting: they carry only its light scattered
# before (the first flights are surface_view's), smooth and a few percent of the glow
DEFICIT_PATHS = 0.25


def fog_glow(pm, camera, n_paths: int, resolution: int, multiple: bool, seed: int = 0,
             threads: int = 0, should_cancel=None, around: Optional[Surroundings] = None,
             n_dirs: int = 32, deposits: float = Tuning.path_deposits,
             nodal: bool = Tuning.path_nodal):
    """(stride, E1, Em, []) on the path lattice of the endless fog ``pm`` (module
    docstring), float32 (LX,LY,LZ,3) W/(m^2 sr), Em None without ``multiple``; the empty
    list: no other medium's share (emissionlight.emission_light's ``cross``).  ``n_dirs``
    directions per lattice point find the surfaces round it (``surface_view``).  None where
    the fog does not glow or its lattice cannot take paths.  ``deposits``, ``nodal``:
    Tuning.path_deposits, Tuning.path_nodal (lightpaths.PathLattice.of)."""
    e1_inf, em_inf = glow_radiance(pm.medium, multiple)
    if camera is None or not np.any(e1_inf + em_inf > 0.0):
        return None
    lat = PathLattice.of(pm, camera, resolution, None if around is None else around.enclosed(pm),
                         deposits=deposits, nodal=nodal)
    if lat is None:
        return None
    shape = tuple(lat.shape) + (3,)
    e1 = np.broadcast_to(e1_inf, shape).astype(np.float32)
    em = np.broadcast_to(em_inf, shape).astype(np.float32) if multiple else None
    if around is None or around.surfaces is None:
        return lat.stride, e1, em, []
    h0, h1 = surface_view(pm, lat, around, n_dirs, seed, threads, should_cancel)
    seen = lat.tent_mass[..., 0] > 0.0
    e1 = fill_hidden((e1_inf * (1.0 - h0)).astype(np.float32), seen)
    st = np.asarray(pm.sigma_t, np.float64)
    absorbs = (np.asarray(pm.sigma_a, np.float64) > 0.0) & (st > 0.0)
    if not (multiple and np.any(absorbs)):
        return lat.stride, e1, em, []
    total = np.where(absorbs, e1_inf + em_inf, 0.0)
    later = 0.0
    got = deficit_starts(pm, around, seed)
    if got is not None:
        p, normal, exitance, albedo, jitter = got
        sets = [(p, exitance * (1.0 - albedo) * total, normal, jitter, 1, None,
                 nearness(pm, p))]
        n = max(1, lat.paths(int(n_paths * DEFICIT_PATHS), n_paths))
        later = lat.mean(_trace_all(sets, n, seed, threads, should_cancel, pm, lat, around,
                                    min_collisions=1)[0])
    em = np.where(absorbs, np.maximum(total * (1.0 - h1) - later - e1, 0.0), 0.0)
    return lat.stride, e1, fill_hidden(em.astype(np.float32), seen), []


def glow_on_medium(fog, solid, pm, camera, n_dirs: int, step: float, multiple: bool,
                   seed: int = 0, surfaces=None, threads: int = 0, should_cancel=None,
                   tuning=None):
    """(stride, E1, Em) (LX,LY,LZ,3) float32 W/(m^2 sr) on the world light's coarse lattice of
    the medium ``pm`` (another medium than the endless ``fog``, among ``solid``): the fog's
    glow that it scatters, from every direction the endless fog's E1_inf and Em_inf
    (glow_radiance) attenuated through the media (``solid``) and hidden by a surface only
    where the fog lies behind it (worldlight.world_light's ``fog_sigma_t``).  E1 = E1_inf U
    (Volume Single), Em = E1_inf C + Em_inf (U + C) (Volume Multiple; None without
    ``multiple``), U the mean transmittance and C the part collided on the way in, as for
    the sky (§7, §9.8).  Left out: the fog's deficit round the surfaces (its first flight,
    which ``fog_glow`` gives the fog itself) and the medium's shade on the fog round it."""
    e1_inf, em_inf = glow_radiance(fog.medium, multiple)
    stride, cshape, cflat, cpts = world_lattice(
        pm, Tuning.ambient_resolution if tuning is None else tuning.ambient_resolution)
    kw = {} if tuning is None else {"tuning": tuning}
    u, c = world_light(solid, pm, World(np.ones(3)), camera, cpts, n_dirs, step, seed=seed,
                       should_cancel=should_cancel, surfaces=surfaces, threads=threads,
                       multiple=True, fog_sigma_t=np.asarray(fog.sigma_t, np.float64), **kw)
    more = on_lattice(cshape, cflat, e1_inf * c + em_inf * (u + c)) if multiple else None
    return stride, on_lattice(cshape, cflat, e1_inf * u), more


def fill_hidden(values: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``values`` (LX,LY,LZ,3) with each lattice point that sees no fog (``seen`` False: its
    tent lies wholly inside a closed mesh or under a ground, PathLattice.tent_mass) set to
    the mean of its neighbours (3x3x3) that do, else 0.  Such a point's own value means
    nothing (inside a white box its directions all meet the box: its glow came out as the
    box's albedo times the endless fog's), yet the voxels beside the box read it through
    their trilinear interpolation."""
    w = seen.astype(np.float32)[..., None]
    acc, cnt = values * w, w.copy()
    for ax in range(3):
        acc = acc + np.roll(acc, 1, axis=ax) + np.roll(acc, -1, axis=ax)
        cnt = cnt + np.roll(cnt, 1, axis=ax) + np.roll(cnt, -1, axis=ax)
    near = np.divide(acc, cnt, out=np.zeros_like(acc), where=cnt > 0.0)
    return np.where(seen[..., None], values, near).astype(np.float32)


def nearness(pm, points) -> np.ndarray:
    """(N,) exp(-d / (2 L)): the odds of drawing a deficit path from ``points`` (N,3, m) at a
    distance d (m) from the fog's grid, L the longest of the fog's diffusion lengths
    1 / sqrt(3 sigma_a (sigma_a + sigma_s (1 - g))) and mean free paths 1 / sigma_t over
    the channels where it absorbs: what a surface farther than a few L from the grid
    takes from it is nil, and there most of the fog's reach lies.  Twice L, so that the odds
    fall slower than the light does (a path from far away that reaches the grid carries
    little more than one from near by)."""
    st = np.asarray(pm.sigma_t, np.float64)
    sa = np.asarray(pm.sigma_a, np.float64)
    ss = np.asarray(pm.sigma_s, np.float64)
    live = (sa > 0.0) & (st > 0.0)
    if not np.any(live):
        return np.ones(len(points))
    tr = np.sqrt(3.0 * sa[live] * (sa[live] + ss[live] * (1.0 - float(pm.g))))
    length = max(float(np.max(1.0 / tr)), float(np.max(1.0 / st[live])))
    idx = pm.to_index(np.asarray(points, np.float64))
    hi = np.array(pm.grid.shape, np.float64) - 1.0
    off = idx - np.clip(idx, 0.0, hi)
    d = np.linalg.norm(off @ np.asarray(pm.i2w, np.float64)[:3, :3].T, axis=1)
    return np.exp(-d / (2.0 * length))


def surface_view(pm, lat, around: Surroundings, n_dirs: int, seed: int, threads: int,
                 should_cancel):
    """(h0, h1) (LX,LY,LZ,3): at each point y of the lattice ``lat`` of the endless fog ``pm``,
    the means over ``n_dirs`` directions w drawn from the phase function about the camera's
    (a light arriving along -w scattered towards the camera) of hit T and of hit (1 - rho) T:
    hit 1 where a surface lies along w (its albedo rho where ``around.bounce``, else 0),
    T = exp(-tau) the transmittance to it through the fog and the other media.  The first
    flights of the deficits exactly (module docstring): the unscattered glow's is e /
    sigma_t h0, that of every order's first flights (e / sigma_a) h1."""
    ss = around.surfaces
    _, pts = lattice_points(pm, lat.shape, lat.stride)
    towards = lat.towards.reshape(-1, 3)
    n = len(pts)
    st = np.asarray(pm.sigma_t, np.float64)
    solid = extinction_media(around.solid)
    sig_t = np.stack([m.sigma_t for m in solid]) if solid else np.zeros((0, 3))
    albedo = surface_albedo(ss) if around.bounce else np.zeros((len(ss.v0), 3))
    _, far = reach(pm)
    far = 2.0 * far
    h0 = np.zeros((n, 3))
    h1 = np.zeros((n, 3))

    def work(a, b):
        m = b - a
        d = -phase_directions(seed + 31, a, b, n_dirs, pm.g, towards[a:b])
        pp = np.repeat(pts[a:b], n_dirs, axis=0)
        t, tri = intersect(ss, pp, d, np.full(len(pp), far))
        hit = tri >= 0
        tau = st[None, :] * t[:, None]
        if solid and np.any(hit):
            tau[hit] += density_lengths(solid, pp[hit], d[hit], t[hit], around.step) @ sig_t
        tr = np.where(hit[:, None], np.exp(-tau), 0.0)
        h0[a:b] = tr.reshape(m, n_dirs, 3).mean(axis=1)
        rho = albedo[np.maximum(tri, 0)]
        h1[a:b] = (tr * (1.0 - rho)).reshape(m, n_dirs, 3).mean(axis=1)

    run_chunks(n, world_chunk(n_dirs), work, threads, should_cancel)
    shape = tuple(lat.shape) + (3,)
    return h0.reshape(shape), h1.reshape(shape)


def deficit_starts(pm, around: Optional[Surroundings], seed: int):
    """(points (N,3) m, normals (N,3), exitance (N,1) m^2 sr, albedo (N,3), jitter m): points
    spread over the surfaces within ``reach(pm)`` (pathstarts.surface_points), lifted off
    their front (the side their normal points to, where the fog is seen: behind a ground or
    inside a closed mesh lies the fog that the lattice leaves out, enclosed.py);
    ``exitance`` pi times the area a point stands for, the watts per W/(m^2 sr) of radiance
    that it carries; ``albedo`` the diffuse albedo where the surfaces reflect the paths
    (``around.bounce``), else 0.  None without surfaces."""
    ss = None if around is None else around.surfaces
    if ss is None:
        return None
    centre, radius = reach(pm)
    got = surface_points(ss, centre, radius, SURFACE_POINTS, np.random.default_rng([seed, 4099]))
    if got is None:
        return None
    p, tri, share = got
    n = ss.normal[tri]
    albedo = surface_albedo(ss)[tri] if around.bounce else np.zeros((len(tri), 3))
    return (p + n * (LIFT * ss.scale), np.ascontiguousarray(n),
            np.pi * share[:, None], albedo, float(np.sqrt(share.min())))
