"""Volume objects (OpenVDB grids) as media.

Blender does not expose voxel values through RNA, so the *evaluated* grids (after modifiers
such as Volume Displace) are written to a scratch .vdb with ``grids.save`` and read back with
the openvdb module bundled with Blender.  Each grid a material reads becomes one medium whose
density is the grid's values (NaN, inf and negatives set to 0; values below the volume's
render clipping set to 0) and whose coefficients are the material's, per unit grid value.
``index_to_world`` = object world matrix @ grid index->object matrix @ offset of the dense
block, so integer ijk of the array are voxel centres, as in OpenVDB.  With the volume's
render space 'Object' (Blender's default) the coefficients and the emission are divided by
the object's scale (``object_space_density``), as Cycles does; fluid domains have no such
setting and stay in world units.

Emission that a grid drives (materials.py's ``emission_terms``: Principled Volume's
blackbody with the grid named by its Temperature Attribute -- commonly 'temperature' or
'flame' in Blender's smoke and fire caches -- and an Attribute node linked into an emission
strength) reads that grid like the density grid and resamples it trilinearly onto the
density grid's lattice (``resample``, ``lattice_emission``); the per-voxel emission becomes
the medium's ``emission_grid`` (the part of the grid outside the density grid's box is not
rendered, with a warning).  Without that grid the blackbody uses the constant Temperature
and an attribute-driven strength is 0 (as in Cycles).  ``lattice_emission`` serves smoke
domains too (fluid.py).

Inputs that node trees drive (fields, materials.py) are evaluated at the voxels of the grid
a medium sits on (``block_medium``): the density is the grid's values x the density field
(Cycles multiplies the Density by the Density Attribute grid), emission fields give
per-voxel emission inside the grid's non-zero voxels (how the hull of active voxels Cycles
shades is approximated here), varying colours their density-weighted means.  Attribute and
Volume Info nodes read the object's grids resampled onto that lattice; Generated maps the
object's bounding box to [0, 1]^3.

A bad file never stops the frame: a missing, truncated or corrupt .vdb, a grid the material
reads but the file lacks, or bad voxel values are reported by object and file name and the
volume is skipped (or sanitised); the rest of the scene renders.
"""
from __future__ import annotations

import os
import sys
import tempfile
from dataclasses import replace
from typing import Dict, List, Optional

import numpy as np

from ...cache import CACHE, digest
from ...media import sanitise
from ...scene import Medium
from .convert import matrix
from .materials import (VolumeCoefficients, colour_grids, default_volume, field_grids,
                        has_fields, merge_by_field, realise, volume_shading)
from .shadergraph import FieldContext

SCALAR_TYPES = {"FLOAT": np.float32, "DOUBLE": np.float64}
# vector grids, read only where a colour wants them (a Principled Volume's Color Attribute)
VECTOR_TYPES = {"VECTOR_FLOAT": np.float32, "VECTOR_DOUBLE": np.float64}


def openvdb_module():
    """The openvdb Python module shipped inside Blender (None when unavailable)."""
    try:
        import openvdb  # noqa: F401
        return openvdb
    except ImportError:
        pass
    import bpy
    ver = f"python{sys.version_info.major}.{sys.version_info.minor}"
    path = os.path.join(bpy.utils.system_resource("PYTHON"), "lib", ver, "site-packages")
    if path not in sys.path:
        sys.path.append(path)
    try:
        import openvdb
        return openvdb
    except ImportError:
        return None


def read_dense(vdb, path: str, name: str, dtype):
    """``(values (nx,ny,nz) float32, ijk of values[0,0,0], background)`` of the active
    bounding box of grid ``name`` in the file ``path``; None when the grid is empty."""
    block = read_window(vdb, path, name, dtype)
    return None if block is None else block[:3]


def read_window(vdb, path: str, name: str, dtype, lo=None, shape=None):
    """``(values float32, ijk of values[0,0,0], background, clipped)`` of grid ``name`` in
    the file ``path``: its active bounding box, or with ``lo``/``shape`` only the part of it
    inside the index box [lo, lo + shape), so a damaged file cannot make the reader allocate
    more than that box (``clipped``: the active box reached outside it).  Vector grids get a
    trailing axis of 3.  None when the grid has no active voxel (in the box).  Needs only
    numpy (``np``) and the openvdb module ``vdb``: fluid.py runs it in a reader process."""
    grid = vdb.read(path, name)
    if grid.activeVoxelCount() == 0:
        return None
    a_lo, a_hi = grid.evalActiveVoxelBoundingBox()
    a_lo = [int(v) for v in a_lo]
    a_hi = [int(v) for v in a_hi]
    clipped = False
    if lo is not None:
        w_lo = [int(v) for v in lo]
        w_hi = [int(v) + int(n) - 1 for v, n in zip(lo, shape)]
        clipped = any(a < w for a, w in zip(a_lo, w_lo)) or any(a > w for a, w in zip(a_hi, w_hi))
        a_lo = [max(a, w) for a, w in zip(a_lo, w_lo)]
        a_hi = [min(a, w) for a, w in zip(a_hi, w_hi)]
        if any(h < l for l, h in zip(a_lo, a_hi)):
            return None
    dims = tuple(h - l + 1 for l, h in zip(a_lo, a_hi))
    vector = type(grid).__name__.startswith("Vec3")
    a = np.zeros(dims + ((3,) if vector else ()), dtype)
    grid.copyToArray(a, ijk=tuple(a_lo))
    background = tuple(float(v) for v in grid.background) if vector else float(grid.background)
    return a.astype(np.float32, copy=False), tuple(a_lo), background, clipped


def translation(origin) -> np.ndarray:
    """4x4 matrix moving index (0, 0, 0) to ``origin`` (a block's ijk origin, voxels)."""
    m = np.eye(4)
    m[:3, 3] = origin
    return m


RESAMPLE_CHUNK = 1 << 18  # lattice points per trilinear batch (bounds the temporary arrays)


def resample(src, dst):
    """Values of grid block ``src`` at the lattice points of block ``dst`` (blocks as read by
    VolumeTranslator: (values, ijk origin, index->object 4x4)), trilinear, 0 outside ``src``'s
    active box: ``(float32 array of dst's shape, fraction of src's sum outside dst's box)``.
    Both grids belong to one object, so only their index->object maps matter.  A vector
    grid (values (X, Y, Z, 3), a colour) is resampled channel by channel."""
    from ...media import trilinear
    values, origin, i2o = src
    if np.ndim(values) == 4:
        parts = [resample((values[..., c], origin, i2o), dst) for c in range(values.shape[3])]
        return np.stack([p[0] for p in parts], axis=-1), max(p[1] for p in parts)
    shape = dst[0].shape
    a = (np.linalg.inv(np.asarray(i2o) @ translation(origin)) @ np.asarray(dst[2])
         @ translation(dst[1]))
    padded = np.zeros(tuple(n + 2 for n in values.shape), np.float32)
    padded[1:-1, 1:-1, 1:-1] = values
    if np.allclose(a, np.round(a)) and np.allclose(a[:3, :3], np.eye(3)):  # the same lattice
        shift = np.round(a[:3, 3]).astype(int)
        out = np.zeros(shape, np.float32)
        lo = np.maximum(0, -shift)
        hi = np.minimum(shape, np.array(values.shape) - shift)
        if np.all(hi > lo):
            out[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = values[
                lo[0] + shift[0]:hi[0] + shift[0], lo[1] + shift[1]:hi[1] + shift[1],
                lo[2] + shift[2]:hi[2] + shift[2]]
    else:
        flat = np.empty(int(np.prod(shape)), np.float32)
        for start in range(0, flat.size, RESAMPLE_CHUNK):
            ijk = np.stack(np.unravel_index(np.arange(start, min(flat.size, start + RESAMPLE_CHUNK)),
                                            shape), axis=1).astype(np.float64)
            flat[start:start + len(ijk)] = trilinear(padded, ijk @ a[:3, :3].T + a[:3, 3] + 1.0)
        out = flat.reshape(shape)
    total = float(np.abs(values).sum())
    if total <= 0.0:
        return out, 0.0
    # the part of src outside dst's box (cells -0.5 .. n - 0.5 in dst's index space)
    inv = np.linalg.inv(a)
    corners = np.array([[i, j, k] for i in (0, values.shape[0] - 1) for j in (0, values.shape[1] - 1)
                        for k in (0, values.shape[2] - 1)], np.float64) @ inv[:3, :3].T + inv[:3, 3]
    if np.all((corners >= -0.5) & (corners <= np.array(shape) - 0.5)):
        return out, 0.0
    ijk = np.stack(np.nonzero(values), axis=1).astype(np.float64)
    d = ijk @ inv[:3, :3].T + inv[:3, 3]
    out_side = np.any((d < -0.5) | (d > np.array(shape) - 0.5), axis=1)
    lost = float(np.abs(values[tuple(ijk[out_side].astype(int).T)]).sum()) / total
    return out, lost


def lattice_emission(co, block, blocks, zero=()):
    """The emission of the closures ``co`` (materials.VolumeCoefficients) at the lattice
    points of grid block ``block`` (values, ijk origin, index->space 4x4: only its shape and
    map are used), W/(m^3 sr): ``(constant RGB >= 0, per-voxel float32 (shape + (3,)) or None,
    lost)``.  Each of ``co.emission_terms`` whose grid is in ``blocks`` (``get(name)`` -> block
    or None; all maps into one space) is resampled onto the lattice and becomes per-voxel
    emission in place of its constant part; a term whose attribute is in ``zero`` (grids that
    exist but hold no data, e.g. a smoke domain's flame without fire) emits as at grid value 0;
    other terms keep their constant (the attribute does not exist: materials.py).  ``lost``:
    grid name -> fraction of its sum outside the lattice's box (not rendered)."""
    emission = np.asarray(co.emission, np.float64)
    grid, lost, sampled = None, {}, {}
    for term in co.emission_terms:
        src = blocks.get(term.attribute) if term.attribute else None
        if src is None:
            if term.attribute in zero:
                emission = emission - term.constant + term.per_voxel(np.zeros(()))
            continue
        if term.attribute not in sampled:
            sampled[term.attribute], outside = resample(src, block)
            if outside:
                lost[term.attribute] = outside
        per = term.per_voxel(sampled[term.attribute])
        grid = per if grid is None else grid + per
        emission = emission - term.constant
    return np.maximum(emission, 0.0), grid, lost


def block_medium(name, coeff, block, blocks, world_matrix, source, zero=(), uniform=False,
                 fields: Optional[FieldContext] = None, where: str = "", warnings=None):
    """``(Medium, lost)`` of closures ``coeff`` (materials.VolumeCoefficients) on grid block
    ``block`` (values, ijk origin, index->object 4x4): the block's values are the density,
    or with ``uniform`` (closures of uniform density) 1 in its non-zero voxels -- how Volume
    objects and fluid domains approximate Cycles' hull of the grids a material reads.  The
    emission the grids in ``blocks`` drive is resampled onto the block (lattice_emission,
    which also gives ``lost`` and reads ``zero``).  Fields (materials.realise) are evaluated
    at the block's voxels with ``fields`` (texture space, frame, cache; messages name
    ``where`` in ``warnings``); the grids they read are resampled onto the block."""
    values, origin, index_to_object = block
    density = (values > 0).astype(np.float32) if uniform else values
    extra = scatter = extinction = None
    if has_fields(coeff):
        def grid_of(name):
            src = blocks.get(name)
            return None if src is None else resample(src, block)[0]
        ctx = fields if fields is not None else FieldContext()
        sampler = ctx.sampler(values.shape, np.asarray(index_to_object) @ translation(origin),
                              world_matrix, grid_of)
        density, coeff, extra, scatter, extinction = realise(
            coeff, density, sampler, grid_of, where, warnings if warnings is not None else [])
        if extra is not None:
            extra = (extra * (values > 0)[..., None]).astype(np.float32)
    emission, grid, lost = lattice_emission(coeff, block, blocks, zero=zero)
    if extra is not None and np.any(extra > 0):
        grid = extra if grid is None else grid + extra
    medium = Medium(name=name, density=density,
                    index_to_world=np.asarray(world_matrix) @ np.asarray(index_to_object)
                    @ translation(origin), sigma_s=coeff.sigma_s, sigma_a=coeff.sigma_a,
                    g=float(coeff.g), emission=emission, source=source, emission_grid=grid,
                    scatter_grid=scatter, extinction_grid=extinction)
    return medium, lost


def object_space_density(world_matrix) -> float:
    """The factor on a Volume object's coefficients when its render space is 'Object'
    (Blender's default: "keeps the volume's appearance when the object is scaled"):
    1 / |M (1, 1, 1) / sqrt(3)| with M the 3x3 part of the object->world matrix, Cycles'
    ``object_volume_density`` (intern/cycles/scene/object.cpp).  A uniform scale s gives
    1 / s: the optical depth across the object stays that of the unscaled object.  1 for a
    degenerate matrix (the object has no extent)."""
    m = np.asarray(world_matrix, np.float64)[:3, :3]
    length = float(np.linalg.norm(m @ np.full(3, 1.0 / np.sqrt(3.0))))
    return 1.0 / length if np.isfinite(length) and length > 1e-12 else 1.0


def scaled_medium(medium: Medium, factor: float) -> Medium:
    """``medium`` with its scattering, absorption and emission times ``factor`` (Cycles
    scales a volume closure's weight, emission included, by ``object_volume_density``)."""
    if factor == 1.0:
        return medium
    grid = None if medium.emission_grid is None else \
        (medium.emission_grid * np.float32(factor)).astype(np.float32)
    return replace(medium, sigma_s=np.asarray(medium.sigma_s) * factor,
                   sigma_a=np.asarray(medium.sigma_a) * factor,
                   emission=np.asarray(medium.emission) * factor, emission_grid=grid)


def bounding_box(ob):
    """``(lo, hi)`` object-space corners of the evaluated object's bounding box (a Volume
    object's texture space), or None."""
    try:
        corners = np.array([tuple(c) for c in ob.bound_box], np.float64)
    except (AttributeError, TypeError):
        return None
    return (corners.min(axis=0), corners.max(axis=0)) if len(corners) else None


def emission_grids(shading) -> List[str]:
    """The grid names the emission terms of ``shading`` read, in order, once each."""
    return list(dict.fromkeys(t.attribute for co in shading for t in co.emission_terms
                              if t.attribute))


def missing_strength_grids(shading, has) -> List[tuple]:
    """``(attribute, socket)`` of the attribute-driven emission strengths of ``shading``
    whose grid ``has(name)`` denies: Cycles reads 0 there."""
    from .emissionterms import AttributeEmissionTerm
    out = []
    for co in shading:
        for t in co.emission_terms:
            if isinstance(t, AttributeEmissionTerm) and not has(t.attribute) \
                    and (t.attribute, t.socket) not in out:
                out.append((t.attribute, t.socket))
    return out


class VolumeTranslator:
    """Turns evaluated Volume objects into media.  Grids are read once per volume datablock,
    so instances of one volume share their density arrays."""

    def __init__(self, warnings: List[str], frame: float = 0.0):
        self.warnings = warnings
        self.frame = frame
        self._cache: Dict[tuple, Optional[tuple]] = {}

    def translate(self, ob, world_matrix: np.ndarray) -> List[Medium]:
        vol = ob.data
        where = f"volume object '{ob.name}'"
        shading = self._shading(ob, where)
        if not shading:
            return []
        grids = {g.name: g for g in vol.grids}
        if not grids:
            self.warnings.append(self._no_grids_message(vol, where))
            return []
        names = [co.attribute for co in shading if co.attribute in grids]
        names += [n for n in emission_grids(shading) + field_grids(shading) if n in grids]
        wanted = [grids[n] for n in dict.fromkeys(names)]
        colours = set(colour_grids(shading))
        for attr, socket in missing_strength_grids(shading, lambda n: n in grids):
            self.warnings.append(f"{where}: the volume has no grid '{attr}' for the attribute "
                                 f"linked into '{socket}'; that emission is 0 (as in Cycles)")
        # grids straight from a file (no modifier changes them) are kept between renders
        blocks = self._blocks(vol, wanted, where, reusable=len(ob.modifiers) == 0,
                              vectors=colours)
        self._fields = FieldContext(bounding_box(ob), self.frame, CACHE.store("voxels"))
        media: List[Medium] = []
        lattices: List[tuple] = []
        uniform: List[VolumeCoefficients] = []
        for co in shading:
            if co.attribute not in grids:
                uniform.append(co)
            elif blocks.get(co.attribute) is not None and np.ndim(blocks[co.attribute][0]) == 4:
                self.warnings.append(f"{where}: grid '{co.attribute}' is a vector grid; only "
                                     "float grids can be used as density; skipped")
            elif blocks.get(co.attribute) is not None:
                block = blocks[co.attribute]
                media.append(self._medium(ob, co, block, grids[co.attribute], world_matrix,
                                          len(shading) > 1, blocks, where))
                lattices.append(block)
        if uniform:
            self._uniform(ob, where, uniform, media, lattices, grids, blocks, world_matrix)
        if getattr(vol.render, "space", "WORLD") == "OBJECT":
            scale = object_space_density(world_matrix)
            media = [scaled_medium(m, scale) for m in media]
        return media

    # -- pieces -----------------------------------------------------------------------------

    def _shading(self, ob, where) -> List[VolumeCoefficients]:
        mats = [s.material for s in ob.material_slots if s.material is not None]
        if not mats:
            mats = [m for m in getattr(ob.data, "materials", []) if m is not None]
        if not mats:
            return [default_volume()]
        mat = mats[0]
        mwhere = f"material '{mat.name}' on {where}"
        shading = volume_shading(mat, mwhere, self.warnings, grids=True)
        if shading is None:
            self.warnings.append(f"{mwhere}: no volume shader is connected, so the volume "
                                 "renders nothing; skipped")
            return []
        return shading

    @staticmethod
    def _path(vol) -> str:
        """The absolute path of the .vdb the volume shows at this frame ('' for a volume made
        by nodes or modifiers without a file)."""
        import bpy
        return bpy.path.abspath(vol.grids.frame_filepath or vol.filepath) if vol.filepath else ""

    def _in_file(self, vol) -> str:
        """`` of '<file>'`` for messages, or '' when the volume has no file."""
        path = self._path(vol)
        return f" of '{path}'" if path else ""

    def _no_grids_message(self, vol, where) -> str:
        path = self._path(vol)
        if vol.filepath and not os.path.exists(path):
            return f"{where}: VDB file '{path}' not found; skipped"
        err = vol.grids.error_message
        return f"{where}: no grids could be loaded from '{path}'" + (f" ({err})" if err else "") \
            + "; skipped"

    def _blocks(self, vol, wanted, where, reusable=False, vectors=()) -> dict:
        """``{grid name: (values, ijk origin, index->object 4x4) or None}`` for the grids in
        ``wanted``, read once per volume datablock: the evaluated grids are saved to one
        scratch file and each wanted grid is read back, sanitised and clipped.  With
        ``reusable`` the grids read from an unchanged .vdb (same path, size and modification
        time) are taken from ``mpp_render.cache`` (kind 'vdb') with their warnings.  Vector
        grids are read (values (X, Y, Z, 3)) when named in ``vectors`` (colours)."""
        out, todo = {}, []
        for g in wanted:
            key = (vol.as_pointer(), g.name)
            if key in self._cache:
                out[g.name] = self._cache[key]
            elif g.name not in (t.name for t in todo):
                todo.append(g)
        if not todo:
            return out
        file_keys = {g.name: self._file_key(vol, g) for g in todo} if reusable else {}
        for g in list(todo):
            hit = CACHE.get("vdb", file_keys[g.name]) if file_keys.get(g.name) else None
            if hit is not None:
                block, messages = hit
                self.warnings.extend(messages)
                out[g.name] = self._cache[(vol.as_pointer(), g.name)] = block
                todo.remove(g)
        if not todo:
            return out
        vdb = openvdb_module()
        if vdb is None:
            self.warnings.append(f"{where}: Blender's openvdb module is not available; skipped")
            return out
        with tempfile.TemporaryDirectory(prefix="mpp_vdb_") as tmp:
            path = os.path.join(tmp, "grids.vdb")
            try:
                vol.grids.save(path)
            except Exception as e:  # RuntimeError from Blender when the grids cannot be written
                self.warnings.append(f"{where}: its grids could not be saved for reading ({e}); "
                                     "skipped")
                return out
            for g in todo:
                before = len(self.warnings)
                block = self._read(vdb, path, vol, g, where, g.name in vectors)
                out[g.name] = self._cache[(vol.as_pointer(), g.name)] = block
                if block is not None and file_keys.get(g.name):
                    CACHE.put("vdb", file_keys[g.name], (block, self.warnings[before:]))
        return out

    def _file_key(self, vol, g):
        """Cache key of grid ``g`` as read from the volume's file (None without a file)."""
        path = self._path(vol)
        try:
            st = os.stat(path) if path else None
        except OSError:
            st = None
        if st is None:
            return None
        return digest(path, st.st_mtime_ns, st.st_size, g.name, str(g.data_type),
                      float(getattr(vol.render, "clipping", 0.0)))

    def _read(self, vdb, path, vol, g, where, vector=False):
        """The sanitised, clipped dense block of grid ``g`` from the scratch file, or None;
        with ``vector`` a vector grid's too (not clipped: a colour)."""
        dtype = SCALAR_TYPES.get(g.data_type)
        is_vector = vector and g.data_type in VECTOR_TYPES
        if is_vector:
            dtype = VECTOR_TYPES[g.data_type]
        if dtype is None:
            self.warnings.append(f"{where}: grid '{g.name}' has type {g.data_type}; only float "
                                 "grids can be used as density; skipped")
            return None
        try:
            block = read_dense(vdb, path, g.name, dtype)
        except Exception as e:  # openvdb raises plain exceptions for bad grids
            block, error = None, e
        else:
            error = None
        if block is None:
            problem = self._file_problem(vol, g)
            if problem:
                self.warnings.append(f"{where}: grid '{g.name}' {problem}; skipped")
            elif error is not None:
                self.warnings.append(f"{where}: grid '{g.name}'{self._in_file(vol)} could not be "
                                     f"read ({error}); skipped")
            else:
                self.warnings.append(f"{where}: grid '{g.name}'{self._in_file(vol)} has no active "
                                     "voxels; skipped")
            return None
        values, origin, background = block
        values, bad = sanitise(values)
        if bad:
            self.warnings.append(f"{where}: {bad} voxels of grid '{g.name}'{self._in_file(vol)} "
                                 "were NaN, infinite or negative; set to 0")
        clip = float(getattr(vol.render, "clipping", 0.0))
        if clip > 0.0 and not is_vector:
            values = np.where(values < clip, np.float32(0.0), values)
        if np.any(np.asarray(background) != 0.0):
            self.warnings.append(f"{where}: the background value {np.asarray(background)} of "
                                 f"grid '{g.name}' is ignored (0 outside the active voxels)")
        return values, origin, matrix(g.matrix_object)

    def _file_problem(self, vol, g) -> str:
        """Why grid ``g`` came out empty when its file is at fault: Blender reads a truncated
        or corrupt file as an empty grid without an error message, but its ``load()`` then
        fails.  '' when the grid loads (it is really empty) or the volume has no file.  The
        file itself is not opened here: the openvdb module aborts the process on some
        corrupt files."""
        path = self._path(vol)
        if not path:
            return ""
        try:
            loaded = bool(g.load())
        except Exception:  # RuntimeError from Blender: not loadable either
            loaded = False
        if loaded:
            return ""
        return f"of '{path}' could not be loaded; the file may be truncated or corrupt"

    def _medium(self, ob, co, block, g, world_matrix, several, blocks, where) -> Medium:
        medium, lost = block_medium(f"{ob.name}:{g.name}" if several else ob.name, co, block,
                                    blocks, world_matrix, "VDB", fields=self._fields,
                                    where=where, warnings=self.warnings)
        self._warn_lost(lost, g.name, where)
        return medium

    def _warn_lost(self, lost, onto, where):
        for name, outside in lost.items():
            self.warnings.append(f"{where}: {outside:.0%} of grid '{name}' lies outside the box "
                                 f"of grid '{onto}'; that part of its emission is not rendered")

    def _uniform(self, ob, where, uniform, media, lattices, grids, blocks, world_matrix):
        """Closures with a uniform density: Cycles fills the hull of the grids the material
        reads with them; that hull is approximated by the voxels where those grids are
        non-zero -- the first density grid's, else (a material whose only grid drives its
        emission) that emission grid's -- with the emission those grids drive on its lattice.
        A material that reads no grid renders nothing in Cycles."""
        names = ", ".join(f"'{n}'" for n in grids)
        if media:
            base_name, block = media[0].name, lattices[0]
        else:
            found = [n for n in emission_grids(uniform) + field_grids(uniform)
                     if blocks.get(n) is not None]
            if not found:
                wanted = sorted({co.attribute for co in uniform if co.attribute})
                what = (f"reads grid {', '.join(repr(w) for w in wanted)}, which the volume "
                        "lacks" if wanted else "reads no grid of the volume")
                self.warnings.append(f"{where}: its material {what} (grids"
                                     f"{self._in_file(ob.data)}: {names}); without a density "
                                     "grid it renders nothing; skipped")
                return
            base_name, block = found[0], blocks[found[0]]
        merged = merge_by_field(uniform)
        for i, coeff in enumerate(merged):
            medium, lost = block_medium(f"{ob.name}:uniform" + (f"{i}" if i else ""), coeff,
                                        block, blocks, world_matrix, "VDB", uniform=True,
                                        fields=self._fields, where=where,
                                        warnings=self.warnings)
            self._warn_lost(lost, base_name, where)
            media.append(medium)
        self.warnings.append(f"{where}: shaders with a uniform density are approximated inside "
                             f"the non-zero voxels of '{base_name}'")

