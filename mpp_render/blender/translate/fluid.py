"""Fluid (Mantaflow) smoke domains as media.

A mesh whose Fluid modifier is a *gas* domain renders its simulation grids, not its mesh, as in
Cycles (``intern/cycles/blender/volume.cpp``, ``geometry.cpp``; Blender's source named, not
copied):

* **Where.**  The grids fill the evaluated mesh's texture space (``texspace_location`` +-
  ``texspace_size``, object space; for a non-adaptive domain its bounding box), cell-centred:
  voxel i of a grid with n cells along an axis sits at ``lo + (i + 0.5) (hi - lo) / n``.  The
  object's world matrix places that box.
* **Which grids.**  Cycles' smoke attributes: ``density``, ``flame``, ``heat``,
  ``temperature`` and ``color``.  With noise on (``use_noise``), density, flame and colour have
  ``noise_scale`` times the domain resolution per axis; heat stays low-resolution.  Following
  the RNA arrays Cycles reads: ``heat`` is Mantaflow's heat grid x 0.5, ``temperature`` is
  ``flame_ignition + flame (flame_max_temp - flame_ignition)`` where flame > 0.01 (else 0),
  ``color`` is the density-weighted RGB (divided by the density for its colour).
* **When.**  Only on frames ``cache_frame_start <= frame <= cache_frame_end`` (Cycles renders
  nothing outside).  Values below the domain's ``clipping`` are 0.
* **From where.**  (1) The live grids of the evaluated domain settings (``density_grid``, ...:
  flat, x fastest); (2) when those are empty -- Mantaflow cannot load a cache in every build,
  e.g. the bpy module -- the baked OpenVDB cache on disk (fluidcache.py), in Blender's layout
  (``DNA_fluid_types.h``, ``fluid.cc``, Mantaflow's ``smoke_script.h`` / ``iovdb.cc``)::

      <cache_directory>/data/fluid_data_####.vdb     density, flame, color_r/g/b and the heat
                                                     grid (named 'temperature'), one voxel per
                                                     cell, ijk (0,0,0) .. resolution - 1
      <cache_directory>/noise/fluid_noise_####.vdb   density_noise, flame_noise, color_*_noise

  where #### is the frame (minus ``cache_frame_offset`` for the Modular and All cache types).
  The file's own transform (voxel size = domain size / resolution, no position) is not used:
  the grids are placed in the texture space as above.  The files are read by the openvdb
  module Blender bundles, with ``vdb.read_window`` (only the index box of the domain's
  resolution is read: sizes in a file are not trusted) in a reader *process* with a time
  limit, because a damaged file can hang or exhaust the openvdb reader; frames read are kept
  in ``mpp_render.cache`` (kind 'fluid') while the file is unchanged.
* **Shading.**  The domain's material (``materials.volume_shading``), as for Volume objects
  (vdb.py): a closure whose density attribute is one of the grids becomes a medium on that
  grid (source 'FLUID', cropped to its non-zero cells) with the closure's emission inside
  it; closures with a uniform density -- or whose Density Attribute names no smoke grid --
  fill the hull of the grids the material reads (Cycles builds the volume's bounds from
  them), approximated by the non-zero cells of the first; a material that reads no grid
  renders nothing.  Only the grids the material needs are read.  A Principled Volume's Color
  Attribute 'color' multiplies its Color by the smoke colour per voxel (materials.py,
  Medium.scatter_grid).  Without a material, or without a
  volume shader, a domain renders nothing (Cycles gives a mesh domain the default *surface*
  shader).  Inputs node trees drive (fields) are evaluated at the medium's cells by
  ``vdb.block_medium``, Generated mapping the texture space to [0, 1]^3 and Attribute /
  Volume Info nodes reading the smoke grids.
* **Fire.**  Emission that grids drive is done by the VDB path's helper
  (``vdb.lattice_emission``), so a domain glows as a Volume object with the same grids and
  shader does: Principled Volume's blackbody with T = Temperature x the grid named by its
  Temperature Attribute ('temperature': 1.5 .. 3 with the domain's default Ignition and
  Maximum, so the node's default Temperature 1000 K gives 1500 .. 3000 K; 'flame': 0 .. 1;
  'heat'), and an Attribute node reading a grid linked into Emission Strength (or an
  Emission shader's Strength): Emission Color x the grid (``svm_node_principled_volume``).
  As in Cycles (``volume.cpp`` gives a domain every smoke attribute its shader asks for,
  filled from the RNA grids), a smoke grid the frame lacks reads as 0 -- no glow, not the
  constant Temperature.  The emitting grid is resampled trilinearly onto the density grid's
  cells (heat is low-resolution, density and flame follow the noise), and the medium covers
  the density's non-zero cells and the cells the emission reaches (Cycles emits wherever the
  shader is evaluated, not only where there is density): a fire without smoke glows on a
  zero density.

Liquid domains are left to the mesh path (their evaluated mesh is the liquid surface).
Anything missing or damaged -- no data, a missing or corrupt cache frame, a grid with NaN,
inf or negative voxels, a grid larger than the domain -- is reported by object and file name;
the rest of the scene renders.
"""
from __future__ import annotations

import os
from typing import Dict, List, Optional, Tuple

import numpy as np

from ...cache import CACHE, digest
from ...media import sanitise
from ...scene import Medium
from .fluidcache import (DATA_GRIDS, NOISE_GRIDS, cache_file, cache_frame, place,
                         read_cache_file)
from .vdb import block_medium, emission_grids, missing_strength_grids, translation
from .materials import VolumeCoefficients, field_grids, merge_by_field, volume_shading
from .shadergraph import FieldContext

STANDARD_GRIDS = ("density", "flame", "heat", "temperature", "color")
SCALAR_GRIDS = ("density", "flame", "heat", "temperature")
# the file grids (our names) each smoke attribute is made from
FILE_GRIDS_FOR = {"density": {"density"}, "flame": {"flame"}, "temperature": {"flame"},
                  "heat": {"heat"}, "color": {"color_r", "color_g", "color_b", "density"}}
FLAME_CUTOFF = 0.01      # flame below this has no temperature (rna_fluid.cc)
HEAT_SCALE = 0.5         # heat_grid = Mantaflow heat x 0.5 (rna_fluid.cc)


def fluid_domain(ob):
    """The domain settings of ``ob``'s Fluid modifier when it is a gas domain enabled for
    rendering, else None (liquid domains and other objects render their mesh)."""
    for mod in getattr(ob, "modifiers", ()):
        if mod.type == "FLUID" and getattr(mod, "fluid_type", "") == "DOMAIN":
            if not getattr(mod, "show_render", True):
                return None
            dse = mod.domain_settings
            return dse if getattr(dse, "domain_type", "GAS") == "GAS" else None
    return None


def texture_box(mesh) -> Tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` object-space corners of the mesh's texture space (its bounding box when
    the texture space is degenerate)."""
    loc = np.array(mesh.texspace_location, np.float64)
    size = np.array(mesh.texspace_size, np.float64)
    if np.all(np.abs(size) > 0) and np.all(np.isfinite(size)) and np.all(np.isfinite(loc)):
        return loc - np.abs(size), loc + np.abs(size)
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)
    return co.min(axis=0), co.max(axis=0)


def cell_to_object(lo, hi, shape) -> np.ndarray:
    """4x4 map from grid index (integer ijk = cell centres) to object space for a grid of
    ``shape`` cells spanning the box [lo, hi]."""
    step = (np.asarray(hi, np.float64) - np.asarray(lo, np.float64)) / np.asarray(shape, np.float64)
    m = np.eye(4)
    m[:3, :3] = np.diag(step)
    m[:3, 3] = np.asarray(lo, np.float64) + 0.5 * step
    return m


def flat_to_grid(flat, shape, channels: int = 1) -> np.ndarray:
    """A flat x-fastest array (Mantaflow's layout) of ``shape`` = (nx, ny, nz) cells to a
    float32 (nx, ny, nz[, channels]) array."""
    nx, ny, nz = (int(v) for v in shape)
    a = np.asarray(flat, np.float32).reshape((nz, ny, nx) + ((channels,) if channels > 1 else ()))
    return np.ascontiguousarray(np.moveaxis(a, (0, 1, 2), (2, 1, 0)))


# -- the grids of one frame -------------------------------------------------------------------

class DomainGrids:
    """The grids of one domain at one frame.

    ``grids``: name -> float32 array (x, y, z) -- 'density', 'flame', 'heat', 'temperature'
    and 'color' (x, y, z, 3), the colour already divided by the density; ``source``: 'live'
    or the cache file read; ``shape``/``low_shape``: the cell counts of the (noise) and the
    low-resolution grids."""

    def __init__(self, shape, low_shape, source: str):
        self.shape, self.low_shape, self.source = tuple(shape), tuple(low_shape), source
        self.grids: Dict[str, np.ndarray] = {}

    def shape_of(self, name: str):
        return self.low_shape if name == "heat" else self.shape


def derived_grids(out: DomainGrids, density, flame, heat, rgb, ignition: float, max_temp: float):
    """Fill ``out`` from the raw grids (any may be None): flame, density, heat (x 0.5),
    temperature from flame, colour from the density-premultiplied ``rgb`` (x, y, z, 3)."""
    if density is not None:
        out.grids["density"] = density
    if flame is not None:
        out.grids["flame"] = flame
        out.grids["temperature"] = np.where(
            flame > FLAME_CUTOFF, np.float32(ignition) + flame * np.float32(max_temp - ignition),
            np.float32(0.0)).astype(np.float32)
    if heat is not None:
        out.grids["heat"] = (heat * np.float32(HEAT_SCALE)).astype(np.float32)
    if rgb is not None and density is not None and rgb.shape[:3] == density.shape:
        with np.errstate(divide="ignore", invalid="ignore"):
            col = np.where(density[..., None] > 1e-6, rgb / density[..., None], np.float32(0.0))
        out.grids["color"] = col.astype(np.float32)
    return out


def live_grids(dse) -> Optional[DomainGrids]:
    """The grids held by the evaluated domain settings, or None when they are empty (all
    zero) or their sizes do not match the domain's resolution."""
    res = tuple(int(v) for v in dse.domain_resolution)
    if min(res) < 1:
        return None
    amp = int(dse.noise_scale) if getattr(dse, "use_noise", False) else 1
    shape = tuple(r * amp for r in res)
    n, n_low = int(np.prod(shape)), int(np.prod(res))

    def get(name, count, channels=1):
        arr = getattr(dse, name, None)
        if arr is None or len(arr) != count * channels:
            return None
        buf = np.zeros(count * channels, np.float32)
        arr.foreach_get(buf)
        return buf

    density, flame, heat, rgba = get("density_grid", n), get("flame_grid", n), \
        get("heat_grid", n_low), get("color_grid", n, 4)
    if not any(a is not None and np.any(a != 0) for a in (density, flame, heat)):
        return None
    out = DomainGrids(shape, res, "live")
    if density is not None:
        out.grids["density"] = flat_to_grid(density, shape)
    if flame is not None:
        out.grids["flame"] = flat_to_grid(flame, shape)
    if heat is not None:
        out.grids["heat"] = flat_to_grid(heat, res)  # already x 0.5 (heat_grid)
    temp = get("temperature_grid", n)
    if temp is not None:
        out.grids["temperature"] = flat_to_grid(temp, shape)
    if rgba is not None:
        c = flat_to_grid(rgba, shape, 4)
        with np.errstate(divide="ignore", invalid="ignore"):
            alpha = c[..., 3:4]
            out.grids["color"] = np.where(alpha > 1e-6, c[..., :3] / alpha, c[..., :3]).astype(np.float32)
    return out


# -- the translator -------------------------------------------------------------------------

class FluidTranslator:
    """Turns evaluated gas domains into media at scene frame ``frame``."""

    def __init__(self, warnings: List[str], frame: int):
        self.warnings = warnings
        self.frame = int(frame)
        self._fields = FieldContext(frame=self.frame)

    def translate(self, ob, dse, world_matrix: np.ndarray) -> List[Medium]:
        where = f"fluid domain '{ob.name}'"
        mat = self._material(ob)
        if mat is None:
            self.warnings.append(f"{where}: no material; a smoke domain renders with its volume "
                                 "material only (Cycles renders it as nothing); skipped")
            return []
        mwhere = f"material '{mat.name}' on {where}"
        local: List[str] = []
        shading = volume_shading(mat, mwhere, local, grids=True)
        if shading is None:
            self.warnings.append(f"{mwhere}: no volume shader is connected, so the domain renders "
                                 "nothing; skipped")
            return []
        start, end = int(dse.cache_frame_start), int(dse.cache_frame_end)
        if not start <= self.frame <= end:
            self.warnings.append(f"{where}: frame {self.frame} is outside its cache frames "
                                 f"{start}..{end}; nothing rendered (as Cycles)")
            return []
        wanted = {co.attribute for co in shading if co.attribute in STANDARD_GRIDS}
        wanted |= {n for n in emission_grids(shading) + field_grids(shading)
                   if n in STANDARD_GRIDS}
        grids = self._grids(ob, dse, where, wanted)
        if grids is None:
            return []
        if "color" in field_grids(shading) and "color" not in grids.grids:
            self.warnings.append(f"{mwhere}: Color Attribute 'color': the domain has no colour "
                                 "grids at this frame; using the Color input")
        self.warnings.extend(local)
        for attr, socket in missing_strength_grids(shading, lambda n: n in SCALAR_GRIDS):
            self.warnings.append(f"{mwhere}: the domain has no scalar grid '{attr}' (its grids: "
                                 + ", ".join(SCALAR_GRIDS) + f") for the attribute linked into "
                                 f"'{socket}'; that emission is 0 (as in Cycles)")
        lo, hi = texture_box(ob.data)
        self._fields = FieldContext((lo, hi), self.frame)
        return self._media(ob, shading, grids, lo, hi, np.asarray(world_matrix, np.float64),
                           float(getattr(dse, "clipping", 0.0)), where)

    # -- pieces -----------------------------------------------------------------------------

    @staticmethod
    def _material(ob):
        mats = [s.material for s in ob.material_slots if s.material is not None]
        if not mats:
            mats = [m for m in getattr(ob.data, "materials", []) if m is not None]
        return mats[0] if mats else None

    def _grids(self, ob, dse, where, wanted) -> Optional[DomainGrids]:
        """This frame's grids (of those named in ``wanted``, a set of STANDARD_GRIDS): the
        live ones, else the baked cache; None with a warning when there is no data."""
        live = live_grids(dse)
        if live is not None:
            return live
        if not wanted:
            return DomainGrids((1, 1, 1), (1, 1, 1), "")  # nothing to read
        res = tuple(int(v) for v in dse.domain_resolution)
        if min(res, default=0) < 1:
            self.warnings.append(f"{where}: the domain has no resolution; skipped")
            return None
        import bpy
        lib = getattr(getattr(ob, "original", ob), "library", None)
        directory = bpy.path.abspath(dse.cache_directory, library=lib) if dse.cache_directory else ""
        frame = cache_frame(dse, self.frame)
        if dse.cache_data_format != "OPENVDB":
            self.warnings.append(f"{where}: its cache format {dse.cache_data_format} cannot be "
                                 "read (only OpenVDB); skipped")
            return None
        data_path = cache_file(directory, frame)
        if not directory or not os.path.isfile(data_path):
            self.warnings.append(f"{where}: no simulation data at frame {self.frame}: cache file "
                                 f"'{data_path}' not found (bake the domain with the OpenVDB "
                                 "format); skipped")
            return None
        amp = int(dse.noise_scale) if dse.use_noise else 1
        shape = tuple(r * amp for r in res)
        keys = set()  # the file grids the wanted attributes are made from
        for name in wanted:
            keys |= FILE_GRIDS_FOR[name]
        data = self._read(data_path, {k: v for k, v in DATA_GRIDS.items() if k in keys}, res,
                          where)
        if data is None:
            return None
        noise = None
        if amp > 1 and keys & set(NOISE_GRIDS):
            noise_path = cache_file(directory, frame, noise=True)
            if dse.cache_noise_format != "OPENVDB":
                self.warnings.append(f"{where}: its noise cache format {dse.cache_noise_format} "
                                     "cannot be read; using the low-resolution data")
            elif not os.path.isfile(noise_path):
                self.warnings.append(f"{where}: noise cache file '{noise_path}' not found; using "
                                     "the low-resolution data")
            else:
                noise = self._read(noise_path,
                                   {k: v for k, v in NOISE_GRIDS.items() if k in keys}, shape,
                                   where)
        hi_res = noise if noise else data
        hi_shape = shape if noise else res
        source = data_path if not noise else f"{data_path}' and '{noise_path}"
        out = DomainGrids(hi_shape, res, source)

        def grid(blocks, name, cells):
            return place(blocks[name], cells) if name in blocks else None

        rgb = None
        if all(c in hi_res for c in ("color_r", "color_g", "color_b")):
            rgb = np.stack([grid(hi_res, c, hi_shape) for c in ("color_r", "color_g", "color_b")],
                           axis=-1)
        return derived_grids(out, grid(hi_res, "density", hi_shape), grid(hi_res, "flame", hi_shape),
                             grid(data, "heat", res), rgb, float(dse.flame_ignition),
                             float(dse.flame_max_temp))

    def _read(self, path, names, shape, where) -> Optional[dict]:
        """Blocks of one cache file by our names (``names``: ours -> file grid name), from
        ``mpp_render.cache`` while the file is unchanged; None (with a warning) when the file
        cannot be read."""
        try:
            st = os.stat(path)
        except OSError as e:
            self.warnings.append(f"{where}: cache file '{path}' cannot be opened ({e}); skipped")
            return None
        key = digest(path, st.st_mtime_ns, st.st_size, sorted(names.items()), list(shape))
        hit = CACHE.get("fluid", key)
        if hit is None:
            blocks, problems, found = read_cache_file(
                path, {ours: (fname, shape) for ours, fname in names.items()})
            hit = (blocks, problems, found)
            if found is not None:
                CACHE.put("fluid", key, hit)
        blocks, problems, found = hit
        if found is None:  # the file as a whole: one message naming it
            why = problems[0] if problems else "could not be read"
            self.warnings.append(f"{where}: cache file '{path}' {why}; frame {self.frame} "
                                 "skipped")
            return None
        for p in problems:
            self.warnings.append(f"{where}: cache file '{path}': {p}")
        for ours, block in blocks.items():
            if block[2]:
                self.warnings.append(f"{where}: grid '{names[ours]}' of '{path}' reaches outside "
                                     f"the domain's {tuple(shape)} cells (another resolution or "
                                     "an adaptive domain?); only the part inside is used")
        return blocks

    def _media(self, ob, shading: List[VolumeCoefficients], grids: DomainGrids, lo, hi,
               world_matrix, clip, where) -> List[Medium]:
        media: List[Medium] = []
        lattices: List[tuple] = []
        uniform: List[VolumeCoefficients] = []
        several = len(shading) > 1
        blocks = _Blocks(self, grids, lo, hi, clip, where)
        for co in shading:
            attr = co.attribute
            if attr is None:
                uniform.append(co)
            elif attr in SCALAR_GRIDS:
                made = self._grid_medium(ob, co, attr, blocks, world_matrix, where, several)
                if made is not None:
                    media.append(made[0])
                    lattices.append(made[1])
            elif co.from_attribute_node:
                self.warnings.append(f"{where}: the domain has no scalar grid '{attr}' (its grids: "
                                     + ", ".join(SCALAR_GRIDS) + "); the Attribute node gives 0, "
                                     "so that shader renders nothing")
            else:
                self.warnings.append(f"{where}: the domain has no scalar grid '{attr}'; that "
                                     "shader's density is uniform (as in Cycles)")
                uniform.append(co)
        if uniform:
            self._uniform(ob, uniform, media, lattices, blocks, world_matrix, where)
        return media

    def _uniform(self, ob, uniform, media, lattices, blocks, world_matrix, where) -> None:
        """Closures with a uniform density (and their emission): Cycles fills the hull of the
        grids the material reads with them, approximated by the voxels where the first of
        those grids is non-zero -- the first density grid's, else the first grid driving an
        emission -- as for Volume objects (vdb.py), with the emission grids drive on its
        lattice.  A material that reads no grid renders nothing in Cycles."""
        if media:
            base_name, block = media[0].name, lattices[0]
        else:
            found = [n for n in emission_grids(uniform) + field_grids(uniform)
                     if n in SCALAR_GRIDS and blocks.get(n) is not None]
            if not found:
                self.warnings.append(f"{where}: its material reads no smoke grid (density, flame, "
                                     "heat or temperature) that holds data at this frame; "
                                     "without one it renders nothing (as in Cycles)")
                return
            base_name = found[0]
            full = blocks.get(base_name)
            first, last = _support_box(full, full)  # with the reach of its interpolation
            block = (_crop(full[0], first, last), tuple(int(v) for v in first), full[2])
        for i, coeff in enumerate(merge_by_field(uniform)):
            medium, lost = block_medium(f"{ob.name}:uniform" + (f"{i}" if i else ""), coeff,
                                        block, blocks, world_matrix, "FLUID", zero=SCALAR_GRIDS,
                                        uniform=True, fields=self._fields, where=where,
                                        warnings=self.warnings)
            for name, outside in lost.items():
                self.warnings.append(f"{where}: {outside:.0%} of grid '{name}' lies outside the "
                                     f"cells of '{base_name}'; that part of its emission is not "
                                     "rendered")
            media.append(medium)
        self.warnings.append(f"{where}: shaders with a uniform density are approximated inside "
                             f"the non-zero voxels of '{base_name}'")

    def _grid_medium(self, ob, co, attr, blocks, world_matrix, where, several):
        """``(medium, its block)`` of a closure whose density is grid ``attr``, or None.  The
        medium covers the grid's non-zero cells and, where the closure's emission reads other
        grids (blackbody, an attribute-driven strength), theirs: Cycles emits wherever the
        shader is evaluated, not only where there is density."""
        full = blocks.lattice(attr)
        if full is None:
            return None  # not a smoke grid
        values, _, i2o = full
        boxes = [_nonzero_box(values)]
        for name in emission_grids([co]):
            src = blocks.get(name)
            if src is not None:
                boxes.append(_support_box(src, full))
        boxes = [b for b in boxes if b is not None]
        if not boxes:
            return None  # nothing non-zero (warned)
        first = np.min([b[0] for b in boxes], axis=0)
        last = np.max([b[1] for b in boxes], axis=0)
        block = (_crop(values, first, last), tuple(int(v) for v in first), i2o)
        # the box holds the emission grids' reach: nothing is lost
        medium, _ = block_medium(f"{ob.name}:{attr}" if several else ob.name, co, block, blocks,
                                 world_matrix, "FLUID", zero=SCALAR_GRIDS, fields=self._fields,
                                 where=where, warnings=self.warnings)
        grid = medium.emission_grid
        if not np.any(medium.density > 0) and (grid is None or not np.any(grid > 0)):
            return None
        return medium, block


class _Blocks:
    """The smoke grids of one domain frame ('color' (X, Y, Z, 3) where the frame has it) as
    vdb.py's grid blocks (values, ijk origin 0,
    index->object 4x4 of their cells in the texture space), sanitised and clipped once each,
    with warnings.  A domain has every smoke grid (Cycles reads one it lacks as zeros), so a
    grid missing from the frame -- e.g. flame without fire, or an empty grid the cache file
    leaves out -- is all zero.  ``get(name)``: None for a grid with no non-zero cell (or a
    name that is no smoke grid); ``lattice(name)``: the block even then (None only for a
    name that is no smoke grid)."""

    def __init__(self, owner, grids: DomainGrids, lo, hi, clip, where):
        self.owner, self.grids, self.lo, self.hi = owner, grids, lo, hi
        self.clip, self.where = clip, where
        self._done: Dict[str, Optional[tuple]] = {}

    def get(self, name):
        block = self.lattice(name)
        return block if block is not None and np.any(block[0] > 0) else None

    def lattice(self, name):
        if name not in STANDARD_GRIDS or (name == "color" and "color" not in self.grids.grids):
            return None   # no colour grids: Cycles leaves the Color as it is
        if name in self._done:
            return self._done[name]
        warn = self.owner.warnings.append
        frame = self.owner.frame
        values = self.grids.grids.get(name)
        src = "live grids" if self.grids.source == "live" else f"'{self.grids.source}'"
        shape = self.grids.shape_of(name)
        if values is None:
            values = np.zeros(shape, np.float32)
        else:
            values, bad = sanitise(values)
            if bad:
                warn(f"{self.where}: {bad} voxels of grid '{name}' in {src} were NaN, infinite or "
                     "negative; set to 0")
            if self.clip > 0.0 and name != "color":
                values = np.where(values < self.clip, np.float32(0.0), values)
        if not np.any(values > 0):
            warn(f"{self.where}: grid '{name}' holds no data at frame {frame} ({src}); it "
                 "reads as 0")
        block = (values, (0, 0, 0), cell_to_object(self.lo, self.hi, shape))
        self._done[name] = block
        return block


def _nonzero_box(values):
    """``(first, last)`` ijk of the non-zero cells of ``values`` (3-D), or None."""
    nz = np.nonzero(values > 0)
    if len(nz[0]) == 0:
        return None
    return np.array([int(a.min()) for a in nz]), np.array([int(a.max()) for a in nz])


def _crop(values, first, last) -> np.ndarray:
    return np.ascontiguousarray(values[first[0]:last[0] + 1, first[1]:last[1] + 1,
                                       first[2]:last[2] + 1])


def _support_box(src, dst):
    """The cells of block ``dst``'s lattice that trilinear samples of block ``src``'s
    non-zero cells can reach (one source cell around them), clamped to ``dst``: ``(first,
    last)`` or None.  Both blocks map into one space (index->space 4x4)."""
    box = _nonzero_box(src[0])
    if box is None:
        return None
    to_dst = np.linalg.inv(dst[2] @ translation(dst[1])) @ src[2] @ translation(src[1])
    lo, hi = box[0] - 1.0, box[1] + 1.0
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) @ to_dst.T
    shape = np.array(dst[0].shape)
    first = np.clip(np.floor(corners[:, :3].min(axis=0)), 0, shape - 1).astype(int)
    last = np.clip(np.ceil(corners[:, :3].max(axis=0)), 0, shape - 1).astype(int)
    if np.any(last < first):
        return None
    return first, last
