"""A lamp's disc beyond the march's reach, folded into the optical depth the field stores.

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
field's: what the march does within the reach).  D is made on a lattice
of every ``stride``-th voxel (Tuning.disc_fold_stride) and interpolated to the voxels (it
follows where the disc's paths cross the smoke, which changes slowly next to the voxels' own
depth).  Within the reach the march ignores it and marches each disc point's path, as
before.  The marches cost 2 ``nodes`` (Tuning.disc_fold_nodes) per lattice point the medium
fills, whatever the image's size; a finer ``stride`` converges to the disc's exact mean at the
voxels.  What it leaves: the phase function (and a spot's cone) weighs the disc's directions
unequally, which the unweighted mean ignores; the disc subtends under 27 degrees beyond the
reach (Tuning.disc_exact), and the march's exact zone takes the nearer points.

Units: world metres; optical depths dimensionless, RGB.
"""
from __future__ import annotations

import numpy as np

from ..lights import disc_transmittance
from ..parallel import run_chunks

__all__ = ["fold_disc"]

TAU_CAP = 200.0   # beyond this depth the light is gone: the field is left as it is
PILOT = 4         # the pilot lattice's stride, in strides
NEGLIGIBLE = 1e-3  # optical depth: a disc that changes none by this much (0.1 %) is not folded
CHUNK = 2048      # lattice points marched per call (threads share the chunks; Esc between)


def _axis_weights(n: int, stride: int):
    """The coarse indices along an axis of ``n`` voxels (every ``stride``-th and the last)
    and, per voxel, its two coarse neighbours' positions in that list and the upper one's
    linear weight."""
    coarse = np.unique(np.r_[np.arange(0, n, stride), n - 1])
    i = np.arange(n)
    hi = np.clip(np.searchsorted(coarse, i, side="left"), 0, len(coarse) - 1)
    lo = np.clip(hi - 1, 0, len(coarse) - 1)
    exact = coarse[hi] == i
    lo = np.where(exact, hi, lo)
    span = np.maximum(coarse[hi] - coarse[lo], 1)
    wt = np.where(exact, 0.0, (i - coarse[lo]) / span)
    return coarse, lo, hi, wt


def _shares(pm, field, channel, light, depth, stride, nodes, threads, should_cancel):
    """(axes, D on the lattice of every ``stride``-th voxel (LX,LY,LZ,3), the lattice points
    marched, the largest |D| among those inside the medium (inf where none is): one outside,
    by a face, sees its disc's paths cross the face's voxels differently, which only the
    voxels on the face read)."""
    shape = pm.grid.shape[:3]
    axes = [_axis_weights(n, stride) for n in shape]
    cshape = tuple(len(a[0]) for a in axes)
    ci = np.stack(np.meshgrid(*[a[0] for a in axes], indexing="ij"), -1).reshape(-1, 3)
    # the lattice points whose stride-wide neighbourhood holds medium, from a summed-volume
    # table of the occupancy
    lo = np.maximum(ci - stride, 0)
    hi = np.minimum(ci + stride + 1, np.array(shape))
    sat = np.zeros(tuple(n + 1 for n in shape), np.int64)
    sat[1:, 1:, 1:] = (pm.grid > 0.0).astype(np.int64).cumsum(0).cumsum(1).cumsum(2)
    total = np.zeros(len(ci), np.int64)
    for corner in range(8):
        pick = [(hi if (corner >> a) & 1 else lo)[:, a] for a in range(3)]
        total += (-1) ** (3 - bin(corner).count("1")) * sat[pick[0], pick[1], pick[2]]
    voxel = float(pm.voxel_size)
    pts = pm.to_world(ci.astype(np.float64))
    dc = np.linalg.norm(pts - np.asarray(light.position, np.float64), axis=1)
    tau = field[ci[:, 0], ci[:, 1], ci[:, 2], channel:channel + 3].astype(np.float64)
    todo = np.flatnonzero((total > 0) & (dc > voxel) & (tau.max(axis=1) < TAU_CAP))
    change = np.zeros((len(ci), 3))
    d = np.zeros((len(todo), 3))

    def work(a, b):
        x, t0 = pts[todo[a:b]], tau[todo[a:b]]
        exact = disc_transmittance(light, x, t0, voxel, nodes=nodes, depth=depth, reach=np.inf)
        stretched = disc_transmittance(light, x, t0, voxel, nodes=nodes)
        ok = np.all((exact > 0.0) & (stretched > 0.0), axis=1)[:, None] & (t0 > 0.0)
        d[a:b] = np.where(ok, np.log(np.where(ok, stretched, 1.0))
                          - np.log(np.where(ok, exact, 1.0)), 0.0)

    run_chunks(len(todo), CHUNK, work, threads, should_cancel)
    change[todo] = d
    inside = pm.grid[tuple(ci[todo].T)] > 0.0   # the medium's own points decide
    return axes, change.reshape(cshape + (3,)), len(todo), \
        float(np.abs(d[inside]).max()) if inside.any() else np.inf


def fold_disc(pm, field: np.ndarray, channel: int, disc_channel: int, light, depth,
              stride: int, nodes: int, threads: int = 0, should_cancel=None) -> int:
    """Write ``light``'s disc's depth change D (module docstring) into
    ``field[..., disc_channel:disc_channel+3]``, from the depth to its centre in
    ``field[..., channel:channel+3]`` at ``pm``'s voxels (0 within a voxel of the lamp and
    where the light is gone).  ``depth``: callable (points, unit dirs, lengths) -> (N,3)
    optical depth through the solid media.  A pilot lattice ``PILOT`` times coarser (at most
    a ``PILOT``-th of the grid's shortest side) comes first: where the disc changes no depth inside the medium on it by ``NEGLIGIBLE`` (a lamp
    inside a homogeneous medium, whose disc points' paths stay in it: the stretch is exact), D stays
    0 and the lattice is not marched.  Returns the lattice points whose disc was marched;
    raises cancel.Cancelled on Esc."""
    marched = 0
    pilot = min(PILOT * stride, max(stride, min(pm.grid.shape[:3]) // PILOT))
    if pilot > stride:
        got = _shares(pm, field, channel, light, depth, pilot, nodes, threads, should_cancel)
        marched = got[2]
        if got[3] < NEGLIGIBLE:
            field[..., disc_channel:disc_channel + 3] = 0.0
            return marched
    axes, c, n, _ = _shares(pm, field, channel, light, depth, stride, nodes, threads,
                            should_cancel)
    # interpolated to the voxels, separably
    for a, (_, lo_a, hi_a, wt) in enumerate(axes):
        w = np.expand_dims(wt, tuple(i for i in range(4) if i != a))
        c = np.take(c, lo_a, axis=a) * (1.0 - w) + np.take(c, hi_a, axis=a) * w
    field[..., disc_channel:disc_channel + 3] = c.astype(np.float32)
    return marched + n
