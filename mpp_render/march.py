"""The camera-ray march: transmittance, single scattering and depth along each ray.

Along a ray x(t) = o + t d the march cuts [t0, t1] (the union of the media's boxes, clipped
to the camera's clip range and the first opaque surface) into segments of length h and reads
every medium's field at one jittered point per segment.  Segments come in super-steps of
``SUPER`` (kernels_np.march): with the media's brick bounds (media.brick_bounds) a super-step
where every medium is empty is skipped (it would add nothing), and one where the medium is
thin (majorant optical depth per step within ``Tuning.adapt_tau``) is cut into fewer, longer
segments, one jittered read each.  Within a segment extinction sigma_t
and in-scattered radiance S are taken as constant, so the segment adds
T * S * (1 - exp(-sigma_t h)) / sigma_t and multiplies T by exp(-sigma_t h): exact for
homogeneous media and stable at any optical depth.

In-scattered radiance at x, per medium m with density rho_m(x):
  S = sum_m rho_m sigma_s,m [ sum_lights p_m(w_l . -d) E_l(x) exp(-tau_l,m(x)) + A_m(x) ]
with E_l the light's irradiance (lights.py), tau the precomputed optical depth to the light
and A the precomputed world light (mpp_render/precompute/); where a medium's scattering
colour varies (PreparedMedium.scatter_grid) sigma_s,m is times its factor c_m(x), read from
the field's scatter colour channels.  The extinction is sigma_t,m rho_m(x), or where its
colour varies (PreparedMedium.extinction_density) sigma_t,m[c] times channel c of the field's
extinction channels.  Rays stop when T < ``T_MIN``.

Emission (the Emission pass) is a medium's constant ``emission`` wherever its density is > 0
plus, for a medium with an emission grid, the grid's value read from the field's emission
channels (precompute/layout.py) wherever it is non-zero (the march's
brick bounds, PreparedMedium.march_bricks, keep those super-steps whole).

Mesh volumes have a sharp surface (media.density_from).  There the optical depth to a light
jumps from 0 outside to sigma_t * distance inside, a kink that trilinear interpolation of
the voxel values smears over a voxel and that darkens the lit surface; so where a sample's
interpolation stencil straddles the surface, the first voxels towards the light are
integrated exactly (``REFINE_STEPS`` half-voxel steps, until the stencil is wholly inside or
outside) and the precomputed optical depth is read only from there on.

The loop itself is a kernel (``kernels.march``: C, or its numpy twin in kernels_np.march);
this module packs the scene for it into a ``kernels.MarchInputs``.  Random numbers come from a counter
hash of (ray key, step, dimension), so both twins draw the same ones.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from . import kernels
from .kernels import LevelField, MarchInputs, MultipleInputs
from .kernels_np import REFINE_STEPS, T_MIN
from .lightrecord import LIGHT_FIELDS
from .lights import pack_light
from .media import PreparedMedium, disc_reaches
from .walk import RHO_TABLE
from .passes import DEPTH_MISS, DEPTH_OPACITY
from .rng import hash32
from .precompute.discdepth import disc_changes
from .precompute.layout import FieldLayout
from .precompute.lightpyramid import MultipleField
from .scene import Camera, Light, Tuning

__all__ = ["MarchContext", "march_rays", "pack_lights", "ray_keys", "REFINE_STEPS", "T_MIN"]

# Longer steps where the medium is thin (Tuning.adapt_tau): the march cuts each super-step of
# SUPER steps into as few (at least one) as keep the density majorant's optical depth per step
# within it (kernels_np.march; never at a mesh volume's surface, where a lighting feature
# changes, or with area / sphere lights, whose jitter the steps average).  Measured on the
# public scenes at 16 spp with 0.1: cloud_vdb 0.72 of the samples at the same error against
# Cycles (0.0066); larger values (0.2, 0.4) biased slab_isotropic when its surfaces were still
# adapted.  With Tuning.skip_empty the kernel gets the media's brick bounds (empty super-steps
# skipped).

MARCH_MAX_LIGHTS = 64   # the lights the march kernel takes (csrc/march.c MAX_LIGHTS)


def pack_lights(lights: List[Light], layout: FieldLayout) -> np.ndarray:
    """(L, LIGHT_FIELDS) float64 records of the lights for the march kernel."""
    out = np.zeros((len(lights), LIGHT_FIELDS))
    beams = layout.beam_channels or [None] * len(lights)
    discs = layout.disc_channels or [None] * len(lights)
    for i, light in enumerate(lights):
        c, b, k = layout.light_channels[i], beams[i], discs[i]
        out[i] = pack_light(light, -1 if c is None else c, -1 if b is None else b,
                            -1 if k is None else k)
    return out


def ray_keys(seed: int, tile: int, n: int) -> np.ndarray:
    """uint32 random keys of the n rays of a tile (the same for any thread count)."""
    return ray_keys_at(seed, tile, np.arange(n))


def ray_keys_at(seed: int, tile: int, ids) -> np.ndarray:
    """``ray_keys``' keys of a tile's rays numbered ``ids`` (ints below 2^32)."""
    base = hash32(np.uint32((seed * 0x632BE5AB + tile * 0x2545F491) & 0xFFFFFFFF))
    return hash32(np.asarray(ids, np.int64).astype(np.uint32) ^ base)


@dataclass
class MarchContext:
    """What the march reads: prepared media, their fields and layout, the lights, the step
    (m) and, for multiple scattering, the per-medium per-light MultipleFields (or None).
    ``multiple``: what the march kernel reads of them (a kernels.MultipleInputs, or None).
    ``gathers``: the context marches a surface's gathers, not camera rays: the traced paths'
    M is read from its moments towards each ray's own origin where it has them
    (MultipleField.moments; ``for_gathers``).  ``glow_moments``: None, or per medium None
    or (stride, h, moments (LX,LY,LZ,12)) of its own glow's light (Precomputed.glow_moments),
    which the gathers read in place of the camera's E1 and Em (``for_gathers``)."""

    media: List[PreparedMedium]
    fields: List[np.ndarray]
    layout: FieldLayout
    lights: List[Light]
    step: float
    multiple_fields: Optional[list] = None
    camera: Optional[Camera] = None
    tuning: Tuning = field(default_factory=Tuning)
    gathers: bool = False
    glow_moments: Optional[list] = None

    def __post_init__(self):
        self.packed = pack_lights(self.lights, self.layout)
        # per light, where the disc points' optical depth is marched (media.disc_reaches),
        # none where its fold found no medium uneven across it (discdepth.disc_changes)
        discs = self.layout.disc_channels or [None] * len(self.lights)
        self.disc_reach = [0.0 if k is not None and not disc_changes(self.fields, k) else r
                           for r, k in zip(disc_reaches(self.media, self.lights,
                                                        self.tuning.disc_exact,
                                                        self.tuning.disc_voxels), discs)]
        self.multiple = None
        if self.multiple_fields is not None:
            amb = self.layout.ambient_multiple_channel
            from .walk import level_table
            per_medium, tables, on = [], [], []
            for pm, mfs, fld in zip(self.media, self.multiple_fields, self.fields):
                ref = next((m for m in mfs if m is not None), None)
                table = np.zeros((1, len(RHO_TABLE), 6)) if ref is None else \
                    level_table(pm.g, pm.sigma_s, pm.sigma_a, ref.h, len(ref.levels))
                on.append(None)
                if ref is not None and (ref.traced or ref.flat):
                    # one level a light: the traced paths' M (paths.py), or a mesh volume's
                    # pyramids flattened by the precompute (precompute.flatten): summed
                    total = np.ascontiguousarray(
                        sum(self.level_of(m) for m in mfs if m is not None), np.float32)
                    tables.append(FLAT_TABLE)
                    on[-1] = on_field(total, ref.stride, fld.shape[:3])
                    if on[-1] is not None:
                        per_medium.append([None] * len(mfs))
                        continue
                    per_medium.append([LevelField([total], ref.stride, ref.h)]
                                      + [None] * (len(mfs) - 1))
                    continue
                per_medium.append([None if m is None else LevelField(m.levels, m.stride, m.h)
                                   for m in mfs])
                tables.append(table)
            self.multiple = MultipleInputs(-1 if amb is None else amb, per_medium, tables,
                                           on if any(f is not None for f in on) else None)

    def level_of(self, msf) -> np.ndarray:
        """The level a traced or flattened MultipleField gives the march: its M towards the
        camera, or for the gathers its moments (12 channels; an M without them as its order
        0, the camera's M read the same from every direction)."""
        if not self.gathers:
            return msf.levels[0]
        if msf.moments is not None:
            return msf.moments
        m = msf.levels[0]
        return np.concatenate([m, np.zeros(m.shape[:3] + (9,), m.dtype)], axis=-1)

    def for_gathers(self) -> "MarchContext":
        """This context for the surfaces' gathers, made once: marching with steps
        ``Tuning.gather_step`` times as long, and reading the traced paths' moments where a
        medium has them (``gathers``); itself when neither changes anything."""
        if self.gathers:
            return self
        made = self.__dict__.get("_for_gathers")
        if made is None:
            moments = any(m is not None and m.moments is not None
                          for mfs in (self.multiple_fields or []) for m in mfs)
            step = self.step * max(1.0, float(self.tuning.gather_step))
            glow = self.multiple_fields is not None and self.glow_moments is not None \
                and self.layout is not None and self.layout.gather_ambient_channel is not None \
                and len(self.lights) < MARCH_MAX_LIGHTS
            if glow:
                made = self._with_glow(step)
            else:
                made = self if not moments and step == self.step else \
                    dataclasses.replace(self, gathers=moments, step=step)
            self.__dict__["_for_gathers"] = made
        return made

    def _with_glow(self, step: float) -> "MarchContext":
        """``for_gathers`` where the media's own glow has moments: the world light read from
        the layout's gather channels (without that glow), and the glow's moments summed with
        the lights' into each medium's one traced level through one more light without
        channels (a dark sun: its level slot where no light has one; its single scattering
        is nothing)."""
        glow_slot = Light("SUN", "glow (gathers)", np.zeros(3))
        fields = []
        for mfs, gm in zip(self.multiple_fields, self.glow_moments):
            mfs = list(mfs) + [None]
            if gm is not None and all(m is None or m.traced for m in mfs):
                stride, h, moments = gm
                mfs[-1] = MultipleField(stride, h, [moments[..., :3]], traced=True,
                                        moments=moments)
            fields.append(mfs)
        return dataclasses.replace(self, lights=list(self.lights) + [glow_slot],
                                   layout=self.layout.for_gathers(1), multiple_fields=fields,
                                   gathers=True, step=step)


# A medium of one density wherever it has any (a mesh volume: density_from thresholds its
# grid) reads the same weights and anisotropies of its level table at every march sample, and
# the direction from a sample to the camera is that of the camera ray through it: its light
# pyramids are summed over levels and lights once, with those weights and the phase
# function towards the camera at each lattice point, into one level (``flatten_levels``)
# that the march reads through this table (weight 4 pi, anisotropy 0: the factor 1), where
# Tuning.flatten says so (precompute.lightpyramid.flattens).
FLAT_TABLE = np.concatenate([np.full((1, len(RHO_TABLE), 3), 4.0 * np.pi),
                             np.zeros((1, len(RHO_TABLE), 3))], axis=2)


def on_field(level: np.ndarray, stride, shape) -> Optional[np.ndarray]:
    """A medium's one flat level (float32 (x,y,z,3), its point j at field index j ``stride``)
    on the field's voxels ``shape`` (X,Y,Z): float32 (X,Y,Z,3), its trilinear values there
    (kernels.upsample_into), or None where that would read differently.  A trilinear function
    is trilinear on each sub-cell of its cells, so with an integer stride the field's own
    trilinear stencil reads the same values the level's would (to float32 rounding) while
    the march sets up one stencil a sample, not two; that needs a level of 3 channels (not
    the gathers' 12 of moments) that covers the field (its last point at or beyond the
    field's last voxel on each axis).  Costs about 12 bytes a voxel, a quarter to a third of
    the field's own (budget.py counts them)."""
    s = float(stride)
    if level.ndim != 4 or level.shape[3] != 3 or not (s >= 1.0 and s.is_integer()):
        return None
    if any((level.shape[a] - 1) * s < shape[a] - 1 for a in range(3)):
        return None
    out = np.zeros(tuple(shape) + (3,), np.float32)
    kernels.upsample_into(out, 0, level, int(s), None)
    return out


def _channels(per_medium):
    """A layout's per-medium channels (None: none) as the kernel takes them: None when no
    medium has one, else -1 for none."""
    if not per_medium or all(c is None for c in per_medium):
        return None
    return [-1 if c is None else c for c in per_medium]


def march_rays(ctx: MarchContext, origins, dirs, t0, t1, axial, keys, jitter=None):
    """March rays; returns dict of per-ray arrays: 'single' (N,3), 'T' (N,3), 'depth' (N,).
    ``jitter``: None, or (bands (N,), count, keys (N,)): each ray's stratum of its steps'
    jitter and its pixel's key (kernels.MarchInputs.jitter_bands), the pixel's samples
    spread over ``count`` strata."""
    amb = ctx.layout.ambient_channel
    em = [np.maximum(np.asarray(m.medium.emission, np.float64).reshape(3), 0.0) for m in ctx.media]
    ec, sc, xc = (_channels(ctx.layout.emission_channels),
                  _channels(ctx.layout.scatter_channels),
                  _channels(ctx.layout.extinction_channels)) \
        if ctx.layout is not None else (None, None, None)
    r = kernels.march(MarchInputs(
        origins, dirs, t0, t1, axial, keys, ctx.fields, [m.w2i for m in ctx.media],
        [m.sigma_s for m in ctx.media], [m.sigma_t for m in ctx.media],
        [float(m.g) for m in ctx.media], [m.threshold for m in ctx.media],
        [m.voxel_size for m in ctx.media], ctx.packed, -1 if amb is None else amb,
        ctx.step, DEPTH_OPACITY, DEPTH_MISS, ctx.multiple,
        em if any(np.any(e > 0) for e in em) else None,
        [m.march_bricks for m in ctx.media] if ctx.tuning.skip_empty else None,
        adapt_tau=ctx.tuning.adapt_tau, emission_channels=ec, roulette=ctx.tuning.roulette,
        disc_reach=ctx.disc_reach, scatter_channels=sc, extinction_channels=xc,
        cell_tau=ctx.tuning.cell_tau, cell_walk=ctx.tuning.cell_walk,
        jitter_bands=None if jitter is None else jitter[0],
        jitter_count=1 if jitter is None else int(jitter[1]),
        jitter_keys=None if jitter is None else jitter[2]))
    return {"single": r.single, "T": r.T, "depth": r.depth, "multiple": r.multiple,
            "steps": r.steps, "emission": r.emission}
