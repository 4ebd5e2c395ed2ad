"""A lamp's disc beyond the march's reach: the depth change the field stores for it.

A point or spot light with a radius r shines from a disc of radius r facing the lit point x
(lights.light_sample).  The march draws one disc point per sample and reads the optical depth
to it as the field's depth to the lamp's centre, tau_c(x), stretched by the disc point's
distance over the centre's, s = d_s / d_c (lights.path_stretch): exact in a homogeneous
medium.  In uneven smoke the disc points' paths part over most of their length, and the mean
of their transmittances, E_j exp(-tau_j), exceeds the mean of the stretched ones,
E_j exp(-s_j tau_c) (Jensen): a 0.3 m lamp in the plume's smoke lit it 2.5 % dark beyond the
reach where the march marches each disc point's own path (media.disc_reaches;
docs/method.md §6).

Beyond that reach the stretched read stays, and the march adds to it the change D(x) this
module stores in the light's own channels (FieldLayout.disc_channels), the same for every
disc point, that makes the stretched reads average to the disc's mean transmittance:

    sum_j w_j exp(-(s_j tau_c + D)) = sum_j w_j exp(-tau_j),
    D = log(sum_j w_j exp(-s_j tau_c)) - log(sum_j w_j exp(-tau_j)),

per channel, with the disc's nodes (s_j, w_j) of lights.disc_transmittance (Gauss-Legendre in
the disc's squared radius, turned by the golden angle) and tau_j each node's path marched
through the solid media (its own path's depth less the stretched centre's, added to the
field's: what the march does within the reach).  D is made on a lattice of every
``stride``-th voxel (Tuning.disc_fold_stride; the world light's, lattice.coarse_lattice) and
interpolated to the voxels (it follows where the disc's paths cross the smoke, which changes
slowly next to the voxels' own depth).  Within the reach the march ignores it and marches
each disc point's path, as before.  The marches cost 2 ``nodes`` (Tuning.disc_fold_nodes)
per lattice point the medium fills, whatever the image's size; a finer ``stride`` converges
to the disc's exact mean at the voxels.  What it leaves: the phase function (and a spot's
cone) weighs the disc's directions unequally, which the unweighted mean ignores; the disc
subtends under 27 degrees beyond the reach (Tuning.disc_exact), and the march's exact zone
takes the nearer points.

An area light's emitter (lights.has_extent) is folded the same way: lights.disc_transmittance
hands it to lights.area_transmittance, whose D is lights.area_depth_change's over a
Gauss-Legendre rule on the emitter, each node weighed by its solid angle; its reach counts
half-diagonals (lights.extent_radius).

Units: world metres; optical depths dimensionless, RGB.
"""
from __future__ import annotations

import numpy as np

from .. import kernels
from ..lights import disc_transmittance
from ..parallel import run_chunks
from .lattice import coarse_lattice

__all__ = ["fold_disc"]

TAU_CAP = 200.0   # beyond this depth the light is gone: the field is left as it is
PILOT = 4         # the pilot lattice's stride, in strides
NEGLIGIBLE = 1e-3  # optical depth: a disc that changes none by this much (0.1 %) is not folded
CHUNK = 2048      # lattice points marched per call (threads share the chunks; Esc between)


def _changes(pm, field, channel, light, depth, stride, nodes, threads, should_cancel):
    """(D (LX,LY,LZ,3) float32 on lattice.coarse_lattice's points ``stride`` voxels apart, 0
    where not made; the points marched; the largest |D| among those inside the medium, inf
    where none is: one outside, by a face, sees its disc's paths cross the face's voxels
    differently, which only the voxels on the face read)."""
    shape, flat, pts = coarse_lattice(pm, stride)
    # a last point beyond the grid's last voxel reads that voxel's depth (coarse_lattice)
    ijk = np.minimum(np.stack(np.unravel_index(flat, shape), axis=1) * stride,
                     np.array(pm.grid.shape[:3]) - 1)
    voxel = float(pm.voxel_size)
    dc = np.linalg.norm(pts - np.asarray(light.position, np.float64), axis=1)
    tau = field[ijk[:, 0], ijk[:, 1], ijk[:, 2], channel:channel + 3].astype(np.float64)
    todo = np.flatnonzero((dc > voxel) & (tau.max(axis=1) < TAU_CAP))
    d = np.zeros((len(todo), 3))

    def work(a, b):
        x, t0 = pts[todo[a:b]], tau[todo[a:b]]
        exact = disc_transmittance(light, x, t0, voxel, nodes=nodes, depth=depth, reach=np.inf)
        stretched = disc_transmittance(light, x, t0, voxel, nodes=nodes)
        ok = np.all((exact > 0.0) & (stretched > 0.0), axis=1)[:, None] & (t0 > 0.0)
        d[a:b] = np.where(ok, np.log(np.where(ok, stretched, 1.0))
                          - np.log(np.where(ok, exact, 1.0)), 0.0)

    run_chunks(len(todo), CHUNK, work, threads, should_cancel)
    lattice = np.zeros(tuple(shape) + (3,), np.float32)
    lattice.reshape(-1, 3)[flat[todo]] = d
    inside = pm.grid[tuple(ijk[todo].T)] > 0.0   # the medium's own points decide
    return lattice, len(todo), float(np.abs(d[inside]).max()) if inside.any() else np.inf


def disc_changes(fields, disc_channel: int) -> bool:
    """Whether any of the media's ``fields`` holds a depth change D in a light's disc
    channels ``disc_channel`` (fold_disc leaves them 0 where its pilot finds the disc changes
    no depth by NEGLIGIBLE: a lamp or emitter inside a homogeneous medium, whose points'
    paths stay in it, or by a mesh volume's face its paths do not cross).  Where none does,
    its points' own depths are the stretched centre's, and neither the march's exact zone
    (march.MarchContext) nor the source's (pathstarts.Surroundings.skip_disc) is run.
    Read a slab of voxels at a time, stopping at the first change (a whole 256^3 field's
    channels take 0.14 s)."""
    return any(f.shape[-1] >= disc_channel + 3 and
               any(np.any(slab[..., disc_channel:disc_channel + 3]) for slab in f)
               for f in fields)


def fold_disc(pm, field: np.ndarray, channel: int, disc_channel: int, light, depth,
              stride: int, nodes: int, threads: int = 0, should_cancel=None) -> int:
    """Write ``light``'s disc's depth change D (module docstring) into
    ``field[..., disc_channel:disc_channel+3]`` (float32, C-contiguous), from the depth to its
    centre in ``field[..., channel:channel+3]`` at ``pm``'s voxels (0 within a voxel of the
    lamp and where the light is gone), made on lattice.coarse_lattice's points and read
    trilinearly at the voxels (kernels.upsample_into).  ``depth``: callable (points, unit
    dirs, lengths) -> (N,3) optical depth through the solid media.  A pilot lattice
    ``PILOT`` times coarser (at most a ``PILOT``-th of the grid's shortest side) comes first:
    where the disc changes no depth inside the medium on it by ``NEGLIGIBLE`` (a lamp inside
    a homogeneous medium, whose disc points' paths stay in it: the stretch is exact), D
    stays 0 and the lattice is not marched.  Returns the lattice points whose disc was
    marched; raises cancel.Cancelled on Esc."""
    marched = 0
    pilot = min(PILOT * stride, max(stride, min(pm.grid.shape[:3]) // PILOT))
    if pilot > stride:
        _, marched, largest = _changes(pm, field, channel, light, depth, pilot, nodes, threads,
                                       should_cancel)
        if largest < NEGLIGIBLE:
            field[..., disc_channel:disc_channel + 3] = 0.0
            return marched
    lattice, n, _ = _changes(pm, field, channel, light, depth, stride, nodes, threads,
                             should_cancel)
    kernels.upsample_into(field, disc_channel, lattice, stride, None)
    return marched + n
