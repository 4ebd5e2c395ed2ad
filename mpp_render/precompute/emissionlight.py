"""Emission as a light source: the light a glowing medium gives off, scattered by that same
medium (docs/method.md, "Emission that lights the scene").

A medium's emission e(x) (W/(m^3 sr): the constant ``Medium.emission`` wherever the density
is > 0, plus the emission grid) sends 4 pi e(x) watts per cubic metre out uniformly over the
sphere.  Light paths (paths.py, lobe 2) start from the emitting voxels in proportion to that
power, each offset by a tent of one voxel, so that they start where the emission
interpolated trilinearly is, as the march reads it (``voxel_starts``).  Their deposits, on
the light pyramid's lattice (precompute.lightpaths.PathLattice), estimate at each lattice
point y

    E1(y) = <integral of L_0(x, w) p(w . v(y); g) dw>_rho,t_y       [W/(m^2 sr)]
    Em(y) = <integral of L_1+(x, w) p(w . v(y); g) dw>_rho,t_y

L_0 the emitted radiance that has not scattered yet (its first flights: the paths traced with
``max_collisions`` 1) and L_1+ what has scattered at least once (every later flight: the
same paths, drawing the same numbers, traced to their end with only the deposits after their
first collision counted, ``min_collisions`` 1, so L_1+ has no noise of the first flights).
The march reads E1 with the sky's light (scattered once towards the camera: Volume Single)
and Em with the sky's multiple scattering (Volume Multiple): both are added to the field's
world channels (precompute/layout.py), interpolated from the lattice to the voxels.  The
paths reflect off the surfaces as the lights' do; the surfaces' own light from the glow is
their gather march's (surfaces.py).

The glow's paths fly through every other medium that scatters, overlapping the glowing one
or apart from it across empty space (precompute.lightpaths.lit_by_glow, the nearest seven;
paths.PathInputs.others), and what they deposit on another medium's lattice lights that
medium (``partners``): a fire lights the smoke beside it and the world's fog round it, by
its direct light and by what its light has scattered since.  The world fog takes that light
in its grid, not beyond it (worldfog.tail carries none of it).  A medium that emits without
scattering (an Emission shader alone, a black fire) lights the others all the same.  The
world fog's own glow, an endless medium's, is fogglow.py's.  A medium that emits nothing
costs nothing.
"""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np

from .. import kernels
from ..media import PreparedMedium
from ..scene import Tuning
from .fogglow import fog_glow
from .lightpaths import (LOBE_MOMENTS, PathLattice, _trace_all, cell_volume, fits_lobe,
                         lobe_light, path_budget)
from .pathstarts import Surroundings

CHUNK = 1 << 20  # voxels interpolated at once when the lattice is added to the field
# paths for the glow where the Paths setting is 0 (the walk: Preview); the walk has no
# emission light of its own
EMISSION_PATHS = 250_000


def emission_light(pm: PreparedMedium, camera, n_paths: int, resolution: int,
                   multiple: bool, seed: int = 0, threads: int = 0, should_cancel=None,
                   around: Optional[Surroundings] = None, partners=(),
                   deposits: float = Tuning.path_deposits, nodal: bool = Tuning.path_nodal,
                   lobe_window: int = Tuning.lobe_window, gathered: bool = False):
    """(stride, E1, Em, cross, moments) on the light pyramid's lattice of ``pm`` (module docstring),
    float32 (LX,LY,LZ,3) W/(m^2 sr); Em None without ``multiple``.  ``n_paths`` paths (at
    most lightpaths.PATHS_PER_POINT per lattice point the medium fills, more with more Paths:
    lightpaths.path_budget), ``around`` the surfaces they reflect off, ``partners``
    (PreparedMedium, PathLattice) the overlapping media they fly through too (lightpaths.traced_multiple), ``cross`` per partner its
    (E1, Em) on its lattice.  None where nothing is emitted or the medium is too dense for
    paths.  ``deposits``, ``nodal``: Tuning.path_deposits, Tuning.path_nodal
    (lightpaths.PathLattice.of); ``lobe_window``: Tuning.lobe_window; ``gathered``: the
    surfaces' gathers read the glow from its paths' moments (``scattered_glow``)."""
    if pm.endless:   # the world fog glows everywhere: its own estimate (fogglow.py)
        got = fog_glow(pm, camera, n_paths, resolution, multiple, seed=seed, threads=threads,
                       should_cancel=should_cancel, around=around, deposits=deposits,
                       nodal=nodal)
        return None if got is None else tuple(got) + (None,)
    e = pm.emitted()
    return scattered_glow(pm, None if e is None else emitting_voxels(e), camera, n_paths,
                          resolution, multiple, seed=seed, threads=threads,
                          should_cancel=should_cancel, around=around, partners=partners,
                          deposits=deposits, nodal=nodal, lobe_window=lobe_window,
                          gathered=gathered)


def scattered_glow(pm: PreparedMedium, emitting, camera, n_paths: int,
                   resolution: int, multiple: bool, seed: int = 0, threads: int = 0,
                   should_cancel=None, around: Optional[Surroundings] = None, partners=(),
                   deposits: float = Tuning.path_deposits, nodal: bool = Tuning.path_nodal,
                   setting: Optional[int] = None, signed: bool = False,
                   first_order: bool = True, odds: Optional[np.ndarray] = None,
                   lobe_window: int = Tuning.lobe_window, gathered: bool = False,
                   starts=()):
    """``emission_light``'s (stride, E1, Em, cross, moments) for the emission ``emitting`` = (flat, e):
    the C-order indices (N,) of the emitting voxels of ``pm``'s padded grid and their
    emission (N,3) W/(m^3 sr) (``emitting_voxels``), or None (nothing emitted, no camera,
    nowhere to scatter, too dense for paths); ``setting``: the Paths setting that scales the
    paths' cap (lightpaths.path_budget; None: ``n_paths``); ``signed``: the lattice's values
    are not stopped at 0 where the nodal move takes them below (PathLattice.mean);
    ``first_order`` False: E1 is not made from the first flights (None in its place).
    ``odds``: None, or (N,) the relative odds of drawing a path from each emitting voxel
    (paths.from_power's bias: the weights stay unbiased).  ``lobe_window``: the own
    lattice's M towards the camera is the paths' lobe fitted to their deposits over windows of
    this many lattice points (lightpaths.lobe_light, Tuning.lobe_window; 0: the deposits).
    ``gathered`` (with ``multiple``): every path also deposits its moments of order 0 and 1
    (paths.py, "Moments"), and ``moments`` is float32 (LX,LY,LZ,12), those of E1 + Em on the
    own lattice, which the surfaces' gathers read towards their own points instead of the
    camera's E1 and Em (march.MarchContext.for_gathers), as they read a lamp's M; else
    None.  ``starts``: more sets of starts (lightpaths._trace_all's: points, power W,
    directions, jitter, lobe), traced with the emitting voxels' (``emitting`` may then be
    None): a surface's fictitious emission (skydeficit.py)."""
    none = emitting is None or not len(emitting[0])
    if (none and not len(starts)) or camera is None:
        return None
    if not pm.scatters and not partners:
        return None   # nothing its light could scatter in
    pm = flown_through(pm)
    lat = PathLattice.of(pm, camera, resolution,
                         None if around is None else around.enclosed(pm), deposits=deposits,
                         nodal=nodal)
    if lat is None:
        return None
    sets = [] if none else voxel_starts(pm, emitting[0], emitting[1], lat.stride)
    if odds is not None:
        sets = [item + (None, np.asarray(odds, np.float64)) for item in sets]
    sets = sets + list(starts)
    lats = [lat] + [plat for _, plat in partners]
    # at most PATHS_PER_POINT per lattice point of every medium the light scatters in
    n = max(1, path_budget(n_paths, sum(la.cells for la in lats), setting))
    # the own lattice's M towards the camera fitted to the paths' lobe, as the lights'
    # (lightpaths.lobe_light); the other media's lattices keep their deposits
    fit = fits_lobe(pm, camera, lobe_window)

    gathered = bool(gathered and multiple)

    def traced(**kw):
        """[own lattice's light, each partner's], and the own lattice's moments or None."""
        accs = _trace_all(sets, n, seed, threads, should_cancel, pm, lat, around,
                          partners=partners, moments=fit or gathered, halves=fit,
                          moment_share=1.0 if gathered else LOBE_MOMENTS, **kw)
        split = None
        if fit:
            accs, split = accs
        m = lat.mean(accs[0], signed)
        own = lobe_light(pm, lat, camera, m, split, lobe_window, threads, should_cancel,
                         signed, around=around) if fit else np.ascontiguousarray(m[..., :3])
        rest = [la.mean(a[..., :3], signed) for la, a in zip(lats[1:], accs[1:])]
        return [own] + rest, (m[..., 3:] if gathered else None)

    once, later = [None] * len(lats), [None] * len(lats)
    moments = []
    if first_order:
        once, mom = traced(max_collisions=1)
        moments.append(mom)
    if multiple:   # the same paths (the same seed), their deposits after a first collision
        later, mom = traced(min_collisions=1)
        moments.append(mom)
    moments = [x for x in moments if x is not None]
    both = np.ascontiguousarray(sum(moments), np.float32) if moments else None
    return lat.stride, once[0], later[0], list(zip(once[1:], later[1:])), both


def flown_through(pm: PreparedMedium) -> PreparedMedium:
    """The medium as the glow's paths fly through it: itself, or where it has no extinction
    (an Emission shader alone) an empty one, which the paths cross unhindered (the tracer
    needs a positive extinction per unit density)."""
    if np.any(np.asarray(pm.sigma_t) > 0.0):
        return pm
    return dataclasses.replace(pm, grid=np.zeros_like(pm.grid), sigma_a=np.ones(3),
                               sigma_t=np.ones(3), emission_grid=None)


def emitting_voxels(e: np.ndarray):
    """(flat, rows): the C-order indices (N,) of the voxels of ``e`` (X,Y,Z,3) that emit and
    their emission (N,3)."""
    flat = np.flatnonzero(e.sum(axis=-1) > 0.0)
    return flat, e.reshape(-1, 3)[flat]


def voxel_starts(pm: PreparedMedium, flat: np.ndarray, e: np.ndarray, stride: int):
    """[(points (N,3) m, power (N,3) W, directions, jitter, lobe 2)]: the emitting voxels
    ``flat`` (C-order indices into ``pm``'s padded grid) of emission ``e`` (N,3)
    W/(m^3 sr), each of power 4 pi e V (V the voxel's volume) and offset by a tent of
    half-width one voxel (``jitter`` 1 / ``stride`` lattice steps), so that the starts
    follow the emission interpolated trilinearly, as the march reads it."""
    power = 4.0 * np.pi * cell_volume(pm, 1) * np.asarray(e, np.float64)
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape[:3]), axis=1).astype(np.float64)
    up = np.zeros((len(flat), 3))
    up[:, 2] = 1.0                                      # any axis: the lobe is uniform
    return [(pm.to_world(ijk), power, up, 1.0 / stride, 2)]


def add_glow(f: np.ndarray, layout, stride: int, once: np.ndarray, more, flat: np.ndarray):
    """Add a glow's light on a lattice ``stride`` voxels apart to the field ``f`` at the voxels
    ``flat``: ``once`` (E1) to the world light's channels of ``layout``
    (layout.FieldLayout), ``more`` (Em, or None) to its multiply scattered part where the
    layout has one."""
    add_lattice(f, layout.ambient_channel, once, stride, flat)
    if more is not None and layout.ambient_multiple_channel is not None:
        add_lattice(f, layout.ambient_multiple_channel, more, stride, flat)


def add_lattice(f: np.ndarray, channel: int, lattice: np.ndarray, stride: int,
                flat: np.ndarray) -> None:
    """Add the trilinear values of ``lattice`` (LX,LY,LZ,3; point k at voxel k ``stride``)
    to ``f``'s channels ``channel``..+2 at the voxels ``flat`` (C-order indices)."""
    view = f.reshape(-1, f.shape[-1])
    shape = f.shape[:3]
    for a in range(0, len(flat), CHUNK):
        part = flat[a:a + CHUNK]
        idx = np.stack(np.unravel_index(part, shape), axis=1).astype(np.float64) / stride
        view[part, channel:channel + 3] += kernels.trilinear(lattice, idx).astype(np.float32)
