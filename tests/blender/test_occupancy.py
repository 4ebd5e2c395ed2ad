"""A mesh volume's occupancy (translate/voxelise.occupancy): its trilinear one-half level, the
march's sharp surface, follows the mesh within a tenth of a voxel, where the binary inside /
outside of the voxel centres puts it on a staircase up to half a voxel off; a box on its own
lattice keeps the binary values exactly."""
import math

import numpy as np
import pytest

from mpp_render.blender.translate.voxelise import inside, lattice, occupancy
from mpp_render.media import SHARP_THRESHOLD, trilinear


def box_mesh(half, rotation):
    """(vertices, triangles) of a closed box of half-sides ``half``, rotated by the 3x3
    ``rotation``."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    v = (corners * np.asarray(half, float)) @ np.asarray(rotation).T
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return v, np.array(tris)


def sphere_mesh(radius, n=96):
    """(vertices, triangles) of a closed UV sphere with n segments and n / 2 rings."""
    rings = n // 2
    verts = [[0, 0, radius]]
    for i in range(1, rings):
        th = math.pi * i / rings
        for j in range(n):
            ph = 2 * math.pi * j / n
            verts.append([radius * math.sin(th) * math.cos(ph),
                          radius * math.sin(th) * math.sin(ph), radius * math.cos(th)])
    verts.append([0, 0, -radius])
    tris = [(0, 1 + j, 1 + (j + 1) % n) for j in range(n)]
    for i in range(rings - 2):
        a, b = 1 + i * n, 1 + (i + 1) * n
        for j in range(n):
            k = (j + 1) % n
            tris += [(a + j, b + j, b + k), (a + j, b + k, a + k)]
    last = len(verts) - 1
    a = 1 + (rings - 2) * n
    tris += [(a + j, last, a + (j + 1) % n) for j in range(n)]
    return np.array(verts, float), np.array(tris)


def rotation(ax, ay, az):
    cx, sx, cy, sy, cz, sz = (math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay),
                              math.cos(az), math.sin(az))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def level_offsets(grid, i2o, points, normals, voxel):
    """Signed distance (voxels, + outwards) from each surface point to where the trilinear
    one-half level of ``grid`` crosses the line along its normal (bisection within +-2
    voxels); NaN where the line does not cross it there."""
    o2i = np.linalg.inv(i2o)
    lo, hi = np.full(len(points), -2.0), np.full(len(points), 2.0)

    def val(t):
        p = points + normals * (t * voxel)[:, None]
        idx = (np.c_[p, np.ones(len(p))] @ o2i.T)[:, :3]
        return trilinear(grid, idx)

    vin, vout = val(lo), val(hi)
    ok = (vin >= SHARP_THRESHOLD) & (vout < SHARP_THRESHOLD)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        inn = val(mid) >= SHARP_THRESHOLD
        lo, hi = np.where(inn, mid, lo), np.where(inn, hi, mid)
    return np.where(ok, 0.5 * (lo + hi), np.nan)


@pytest.mark.parametrize("angles", [(0.0, 0.0, 0.0), (0.3, 0.5, 0.7), (1.1, -0.4, 0.2)])
def test_a_box_face_is_the_half_level_within_a_tenth_of_a_voxel(angles):
    rot = rotation(*angles)
    half = np.array([1.0, 0.7, 0.5])
    v, t = box_mesh(half, rot)
    shape, i2o = lattice(v, np.eye(4), 40)
    occ = occupancy(v, t, i2o, shape)
    assert occ.dtype == np.float32 and occ.min() >= 0.0 and occ.max() <= 1.0
    # the voxel centres at or above one half are the even-odd rule's inside ones
    np.testing.assert_array_equal(occ >= 0.5, inside(v, t, i2o, shape))
    voxel = float(i2o[0, 0])
    binary = inside(v, t, i2o, shape).astype(np.float32)
    rng = np.random.default_rng(4)
    errs, errs_bin = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            # points on the face away from its edges, and its outward normal
            uv = (rng.random((400, 3)) * 2 - 1) * 0.8 * half
            uv[:, axis] = sign * half[axis]
            n = np.zeros(3)
            n[axis] = sign
            pts, nrm = uv @ rot.T, np.tile(rot @ n, (400, 1))
            # the padded grid the march reads (zeros beyond the lattice)
            errs.append(level_offsets(np.pad(occ, 1), i2o @ _shift(1), pts, nrm, voxel))
            errs_bin.append(level_offsets(np.pad(binary, 1), i2o @ _shift(1), pts, nrm,
                                          voxel))
    e, eb = np.concatenate(errs), np.concatenate(errs_bin)
    assert not np.any(np.isnan(e))
    rms, rms_bin = np.sqrt(np.nanmean(e ** 2)), np.sqrt(np.nanmean(eb ** 2))
    print(f"angles {angles}: the half level off the face by rms {rms:.4f} voxels "
          f"(binary centres {rms_bin:.4f}), worst {np.abs(e).max():.4f}")
    assert np.abs(e).max() < 0.1
    if angles == (0.0, 0.0, 0.0):   # faces on the cells' faces: the binary voxels, exactly
        np.testing.assert_array_equal(occ, binary)
    else:
        assert rms < 0.3 * rms_bin


def _shift(pad):
    s = np.eye(4)
    s[:3, 3] = -float(pad)
    return s


def test_a_sphere_is_round_within_a_tenth_of_a_voxel():
    v, t = sphere_mesh(1.0, 192)
    shape, i2o = lattice(v, np.eye(4), 48)
    occ = occupancy(v, t, i2o, shape)
    binary = inside(v, t, i2o, shape).astype(np.float32)
    voxel = float(i2o[0, 0])
    rng = np.random.default_rng(5)
    n = rng.normal(size=(2000, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    e = level_offsets(np.pad(occ, 1), i2o @ _shift(1), n, n, voxel)
    eb = level_offsets(np.pad(binary, 1), i2o @ _shift(1), n, n, voxel)
    # the mesh's facets lie inside the round sphere by up to 1 - cos(pi / 192) of its radius
    print(f"sphere: the half level off the surface by rms {np.sqrt(np.mean(e ** 2)):.4f} "
          f"voxels, worst {np.abs(e).max():.4f} (binary centres rms "
          f"{np.sqrt(np.mean(eb ** 2)):.4f}, worst {np.abs(eb).max():.4f})")
    assert not np.any(np.isnan(e))
    assert np.abs(e).max() < 0.1 and np.sqrt(np.mean(e ** 2)) < 0.3 * np.sqrt(np.mean(eb ** 2))


def test_an_empty_or_flat_mesh_gives_no_inside():
    v, t = box_mesh([1.0, 1.0, 1.0], np.eye(3))
    shape, i2o = lattice(v, np.eye(4), 8)
    occ = occupancy(v, t[:0], i2o, shape)   # no triangles: nothing inside, no ramp
    assert occ.shape == shape and not np.any(occ >= 0.5) and np.all(occ == 0.0)
