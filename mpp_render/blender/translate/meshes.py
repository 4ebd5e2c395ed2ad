"""Mesh objects: volume materials become voxelised media, other materials opaque surfaces.

A volume mesh's medium is its interior on a voxel lattice in object space (voxelise.py).
Closures whose inputs node trees drive (fields, materials.py) are evaluated at the voxel
centres (materials.realise): the density grid is the inside mask x the density field, the
emission fields give ``Medium.emission_grid`` (inside the mesh only), a varying scattering
colour ``Medium.scatter_grid``, a varying colour of the extinction ``Medium.extinction_grid``.
A mesh has no grids, so Attribute and Volume Info nodes read 0 (as
in Cycles).  Generated coordinates map the mesh's texture space (its bounding box unless set
otherwise) to [0, 1]^3.  Closures with different density fields become one medium each.

A medium whose density a field varies (or whose colour fields vary its extinction's
brightness or colour, materials.realise) has the source ``FIELD_SOURCE`` rather than 'MESH':
the renderer (media.py) gives a 'MESH' medium a sharp surface of *one* density (its grid
thresholded at one half), so a varying density is rendered as a grid, interpolated
trilinearly (the surface then blurs over a voxel).
"""
from __future__ import annotations

from typing import Dict, List

import numpy as np

from ...scene import Medium, Surface
from .materials import has_fields, is_linked, merge_by_field, realise, volume_shading
from .surfaceshading import surface_shading
from .shadergraph import FieldContext
from .voxelise import is_closed, lattice, occupancy


def mesh_arrays(mesh):
    """``(vertices (N,3) float64 object space, triangles (M,3) int64, material_index (M,)
    int64)`` copied from a Blender mesh."""
    n = len(mesh.vertices)
    co = np.empty(n * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    if len(mesh.loop_triangles) == 0 and len(mesh.polygons) > 0:
        mesh.calc_loop_triangles()
    m = len(mesh.loop_triangles)
    tri = np.empty(m * 3, np.int32)
    mat = np.zeros(m, np.int32)
    if m:
        mesh.loop_triangles.foreach_get("vertices", tri)
        mesh.loop_triangles.foreach_get("material_index", mat)
    return (co.reshape(n, 3).astype(np.float64), tri.reshape(m, 3).astype(np.int64),
            mat.astype(np.int64))


FIELD_SOURCE = "MESH_FIELD"  # a mesh medium with a varying density (module docstring)


def texture_space(mesh, verts):
    """``(lo, hi)`` object-space box of the mesh's texture space (Blender's
    ``texspace_location`` +- ``texspace_size``; the vertices' bounding box without one)."""
    loc = getattr(mesh, "texspace_location", None)
    size = getattr(mesh, "texspace_size", None)
    if loc is None or size is None:
        return verts.min(axis=0), verts.max(axis=0)
    loc, size = np.asarray(loc, np.float64), np.asarray(size, np.float64)
    size = np.where(size != 0.0, size, 1.0)
    return loc - size, loc + size


def slot_materials(ob, mesh) -> list:
    """The material of each slot of ``ob`` (None for an empty slot)."""
    mats = [slot.material for slot in ob.material_slots]
    if not mats:
        mats = list(getattr(mesh, "materials", []))
    return mats


class MeshTranslator:
    """Turns evaluated mesh instances into media and surfaces.

    ``resolution``: voxels along the longest world side of a volume mesh.  Voxelisations are
    cached per mesh and lattice shape, so instances of one mesh are voxelised once; fields
    evaluated on a lattice are cached beside them under the field's key (and the object's
    matrix when the field reads world positions), so an unchanged tree is evaluated once
    across frames."""

    def __init__(self, resolution: int, warnings: List[str]):
        self.resolution = int(resolution)
        self.warnings = warnings
        self._cache: Dict[tuple, np.ndarray] = {}

    def translate(self, ob, mesh, world_matrix: np.ndarray, cache_key=None):
        """``(media, surfaces)`` for the evaluated object ``ob`` with geometry ``mesh`` placed
        by ``world_matrix`` (4x4)."""
        verts, tris, mat_index = mesh_arrays(mesh)
        if tris.size == 0:
            return [], []
        mats = slot_materials(ob, mesh)
        slot_of = np.clip(mat_index, 0, max(len(mats) - 1, 0))
        per_slot = {int(s): (mats[s] if s < len(mats) else None) for s in np.unique(slot_of)}
        volumes = {}
        for s, mat in per_slot.items():
            where = self._where(ob, mat)
            shading = volume_shading(mat, where, self.warnings) if mat is not None else None
            if shading is not None:
                volumes[s] = (mat, shading)
        if volumes:
            texspace = texture_space(mesh, verts)
            return self._medium(ob, verts, tris, per_slot, volumes, world_matrix, cache_key,
                                texspace), []
        return [], self._surfaces(ob, verts, tris, slot_of, per_slot, world_matrix)

    @staticmethod
    def _where(ob, mat) -> str:
        return f"material '{mat.name}' on object '{ob.name}'" if mat is not None else f"object '{ob.name}'"

    def _medium(self, ob, verts, tris, per_slot, volumes, world_matrix, cache_key,
                texspace=None) -> List[Medium]:
        slot, (mat, shading) = next(iter(volumes.items()))
        where = self._where(ob, mat)
        others = [m.name for s, m in per_slot.items() if s != slot and m is not None]
        if others:
            self.warnings.append(f"object '{ob.name}': only its first volume material "
                                 f"'{mat.name}' is used for the whole mesh; ignoring "
                                 + ", ".join(f"'{n}'" for n in others))
        if is_linked(mat.node_tree, "Surface"):
            self.warnings.append(f"{where}: the surface shader of a volume material is not "
                                 "supported; only its volume is rendered")
        for co in shading:
            if co.from_attribute_node:
                self.warnings.append(f"{where}: attribute '{co.attribute}' has no values inside a "
                                     "mesh; using a uniform density")
        if not shading:
            return []
        if not is_closed(tris):
            self.warnings.append(f"object '{ob.name}': the mesh is not closed, so its volume "
                                 "interior is approximate")
        lat = lattice(verts, world_matrix, self.resolution)
        if lat is None:
            self.warnings.append(f"object '{ob.name}': the mesh is flat and has no interior; "
                                 "its volume is skipped")
            return []
        shape, i2o = lat
        key = (cache_key, shape) if cache_key is not None else None
        # a plain volume's medium is the sharp one-half level of its occupancy (voxelise.
        # occupancy); a field's density is its value at the voxel centres inside, 0 outside
        occ = self._cache.get(key) if key is not None else None
        if occ is None:
            occ = occupancy(verts, tris, i2o, shape)
            if key is not None:
                self._cache[key] = occ
        mask = None   # the centres inside, for a field's density (made once, if one has a field)
        groups = merge_by_field(shading)
        fields = FieldContext(texspace, store=self._cache if key is not None else None)
        sampler = fields.sampler(shape, i2o, world_matrix)
        media = []
        for i, coeff in enumerate(groups):
            fielded = has_fields(coeff)
            if fielded and mask is None:
                mask = (occ >= 0.5).astype(np.float32)
            density, grid, scatter = (mask if fielded else occ), None, None
            extinction = None
            varies = coeff.density_field is not None
            if fielded:
                density, coeff, grid, scatter, extinction = realise(
                    coeff, mask, sampler, lambda name: None, where, self.warnings)
                # a field may have varied the density (its colours the extinction's brightness)
                varies = varies or not np.array_equal(density, mask) or extinction is not None
                if grid is not None:
                    grid = (grid * mask[..., None]).astype(np.float32)
                    if not np.any(grid > 0):
                        grid = None
            if fielded and not np.any(density > 0) and grid is None \
                    and not np.any(coeff.emission > 0):
                continue  # nothing here (a field that is 0 inside the mesh)
            media.append(Medium(name=ob.name if len(groups) == 1 else f"{ob.name}:{i}",
                                density=density, index_to_world=world_matrix @ i2o,
                                sigma_s=coeff.sigma_s, sigma_a=coeff.sigma_a,
                                g=float(coeff.g), emission=coeff.emission,
                                source=FIELD_SOURCE if varies else "MESH", emission_grid=grid,
                                scatter_grid=scatter, extinction_grid=extinction))
        return media

    def _surfaces(self, ob, verts, tris, slot_of, per_slot, world_matrix) -> List[Surface]:
        world = verts @ world_matrix[:3, :3].T + world_matrix[:3, 3]
        if len(per_slot) == 1:
            mat = next(iter(per_slot.values()))
            shading = surface_shading(mat, self._where(ob, mat), self.warnings)
            return [Surface(ob.name, world, tris.copy(), **shading)]
        out = []
        for s, mat in per_slot.items():
            sel = tris[slot_of == s]
            used, local = np.unique(sel, return_inverse=True)
            shading = surface_shading(mat, self._where(ob, mat), self.warnings)
            name = f"{ob.name} [{mat.name if mat is not None else 'no material'}]"
            out.append(Surface(name, world[used], local.reshape(-1, 3).astype(np.int64),
                               **shading))
        return out
