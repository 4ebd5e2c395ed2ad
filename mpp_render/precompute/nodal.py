"""The traced paths' lattice values at the lattice points themselves, not at their tents'
centroids.

A lattice point y's traced mean (lightpaths.PathLattice.mean) is

    M̄(y) = ∫ ρ t_y S d³x / ∫ ρ t_y d³x,

the density-weighted mean of the in-scattered light S under y's tent t_y.  Where the
density under the tent is even it is S(y) to second order; where it is not (a mesh volume's
surface, a cloud's edge, the voxels behind a ground left out) it is S at the tent's
density-weighted centroid c(y) = ∫ ρ t_y x / ∫ ρ t_y, to first order: up to about a third of a
lattice step inside the medium from a point on its surface.  The march reads M trilinearly
between the lattice points, which is exact for a linear S only if each point holds S(y).
So each point's value is moved along S's gradient from its centroid to itself:

    M(y) = M̄(y) + ∇S · (y − c(y)),

∇S fitted by least squares to the differences of the traced means of y's 26 neighbours
against their centroids' offsets (``nodal_values``).  Where the density is even c(y) = y
and nothing changes; as the lattice is refined the correction vanishes with the step.

Units: offsets and centroids in lattice steps (index coordinates over the stride); M in
whatever unit it comes (W/(m^2 sr)); the correction is linear in M, channel by channel.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .. import kernels
from .source import tent_restrict

# ridge (lattice steps^2) added to the least-squares normal matrix: an axis along which no
# neighbour holds medium gets no gradient, not an ill-conditioned one
RIDGE = 0.01


@lru_cache(maxsize=16)
def box_tent_moment_weights(stride: int) -> tuple:
    """((t, w), ...): the first moment, in lattice steps, of the tent of half-width
    ``stride`` voxels (height 1 / stride, integral 1) over the voxel [t - 1/2, t + 1/2],
    t = -stride..stride: ∫ T(u) u / stride du over the voxel (source.box_tent_weights' twin
    for the centroid).  Odd in t; exact (the integrand is piecewise quadratic: Simpson's
    rule on each piece)."""
    s = float(stride)

    def piece(a, b):   # ∫_a^b T(u) u/s du with T linear on [a, b]
        if b <= a:
            return 0.0
        f = lambda u: max(s - abs(u), 0.0) / (s * s) * u / s  # noqa: E731
        return (b - a) / 6.0 * (f(a) + 4.0 * f(0.5 * (a + b)) + f(b))

    out = []
    for t in range(-stride, stride + 1):
        lo, hi = t - 0.5, t + 0.5
        cuts = sorted({lo, hi} | {c for c in (-s, 0.0, s) if lo < c < hi})
        out.append((t, sum(piece(a, b) for a, b in zip(cuts, cuts[1:]))))
    return tuple(out)


def centroid_offsets(rho: np.ndarray, stride: int, shape, mass: np.ndarray) -> np.ndarray:
    """float64 (LX,LY,LZ,3): each lattice point's tent centroid c(y) - y in lattice steps,
    weighed by ``rho`` (X,Y,Z, the density over each voxel's cell, as the tent ``mass``
    (LX,LY,LZ), its box-tent restriction, source.tent_restrict, takes it); 0 where the tent
    holds no density."""
    out = np.zeros(tuple(shape) + (3,))
    moment_w = dict(box_tent_moment_weights(stride))
    for a in range(3):
        m = rho
        for axis in range(3):
            m = tent_restrict(m, axis, stride, shape[axis], boxed=True,
                              weights=moment_w if axis == a else None)
        np.divide(m, mass, out=out[..., a], where=mass > 0.0)
    return out


def tent_mass(rho: np.ndarray, stride: int, shape, centroids: bool):
    """(mass (LX,LY,LZ), offsets or None): the box-tent restriction of ``rho`` (X,Y,Z, the
    density over each voxel's cell) to the lattice ``stride`` voxels apart of ``shape``
    (source.tent_restrict), and with ``centroids`` each point's ``centroid_offsets``."""
    mass = rho
    for axis in range(3):
        mass = tent_restrict(mass, axis, stride, shape[axis], boxed=True)
    return mass, (centroid_offsets(rho, stride, shape, mass) if centroids else None)


def nodal_values(mean: np.ndarray, offsets: np.ndarray, mass: np.ndarray,
                 signed: int = 0) -> np.ndarray:
    """``mean`` (LX,LY,LZ,C) of tent means moved to the lattice points (module docstring):
    M̄ − ∇S · offsets at each point whose offset is not 0, ∇S per channel by least squares
    on the differences to its 26 neighbours that hold ``mass`` (LX,LY,LZ) > 0, against their
    centroids' offsets from its own; each neighbour weighs m_z / (m_z + m_y), so that a
    neighbour holding a sliver of the medium (and few deposits) counts little; ridge
    ``RIDGE``.  Points without mass keep their mean; the first C - ``signed`` channels
    (light, which is never negative) stop at 0, the last ``signed`` (the moments' first
    order, paths.py) do not.  Float32 out (kernels.nodal_fit)."""
    return kernels.nodal_fit(mean, offsets, mass, int(signed), RIDGE)
