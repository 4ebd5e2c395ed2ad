"""The precompute's entry: every medium's field (layout.py) and, with multiple scattering, the
light pyramids (lightpyramid.py), stage by stage."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, List, Optional

import numpy as np

from .. import kernels
from ..media import PreparedMedium, delta_scaled, density_from
from ..parallel import check
from ..scene import Camera, Light, Tuning, World
from .lattice import MULTIPLE_RESOLUTION, grid_points, lamp_resolution, needed_flat
from .layout import FieldLayout, field_layout, glow_gathered
from .lightdepth import (SHADOW_TAU, light_optical_depth, near_sharp_surfaces, soft_visibility,
                         split_fog, sweep_light)
from .discdepth import disc_changes, fold_disc
from .flatten import flattened
from .fogglow import glow_on_medium
from .emissionlight import EMISSION_PATHS, add_glow, add_lattice, emission_light
from .lightpaths import (across_media, lit_by_glow, overlapping, partner_lattice, start_power,
                         too_dense, traced_multiple)
from .pathstarts import Surroundings
from .skydeficit import deficit_paths, sky_deficit
from .lightpyramid import MultipleField, multiple_field
from .source import peak_light
from .worldlight import fill_world_light


@dataclass
class Precomputed:
    """``fields``: per medium (X,Y,Z,C) float32 (layout.py); ``multiple``: per medium, per
    light, a MultipleField or None (multiple scattering off, dark light, or no scattering).
    ``glow_moments``: None, or per medium None or (stride, h, float32 (LX,LY,LZ,12)) the
    moments of its own glow's light (precompute.emissionlight), which the surfaces' gathers
    read (FieldLayout.gather_ambient_channel); part of the world light, as the glow is."""

    fields: List[np.ndarray]
    layout: FieldLayout
    multiple: list = field(default_factory=list)
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)
    glow_moments: Optional[list] = None


def precompute(media: List[PreparedMedium], lights: List[Light], world: World, camera: Camera,
               n_dirs: int = 64, step_factor: float = 1.0, seed: int = 0,
               should_cancel: Optional[Callable[[], bool]] = None,
               progress: Optional[Callable[[float, str], None]] = None,
               surfaces=None, threads: int = 0, multiple: bool = False,
               multiple_resolution: int = MULTIPLE_RESOLUTION, multiple_paths: int = 0,
               tuning: Tuning = Tuning(), surface_bounce: bool = True,
               glow: bool = True) -> Precomputed:
    """Field arrays for every medium, and with ``multiple`` the light pyramids; raises
    cancel.Cancelled when ``should_cancel`` says so.  ``surfaces`` (a SurfaceSet or None)
    shadow the lights and the sky.  Media that cannot scatter (sigma_s = 0) get no
    multiple-scattering data.  ``multiple_paths``: light paths traced per light and medium
    for multiple scattering (precompute.lightpaths); 0: the walk of the light pyramid.  ``tuning``: the
    method's knobs (scene.Tuning, with the Settings).  ``surface_bounce``: the traced paths
    start on the lit surfaces and reflect off them (else the surfaces only absorb them).
    ``glow``: the light the media give off, scattered in them (precompute.emissionlight), is
    added to the world channels (cache.precompute_cached's part without the world leaves it
    out).  The constant sky's light off the surfaces is the sky's (precompute/skydeficit.py),
    in the world channels."""
    t_start = time.perf_counter()
    delta = [delta_scaled(pm) for pm in media]
    # a lamp's disc is folded into its own channels where a medium other than the world's
    # fog (homogeneous: the stretch is exact in it) lies round it (discdepth.py)
    traces = multiple and multiple_paths > 0 and camera is not None
    # the surfaces' gathers read a medium's own glow from its paths' moments, the rest of
    # the world light from a second copy of its channels (layout.glow_gathered)
    gather_glow = glow_gathered(media, traces, surfaces, tuning.gather_moments, glow)
    layout = field_layout(media, lights, world.color, multiple, delta, peak=multiple_paths <= 0,
                          glow=glow, disc=tuning.disc_fold_stride > 0
                          and any(not pm.endless for pm in media), gather_glow=gather_glow)
    world_lit = bool(np.any(np.asarray(world.color) > 0))
    chans, beams = layout.light_channels, layout.beam_channels or [None] * len(lights)
    discs = layout.disc_channels or [None] * len(lights)
    c = layout.channels
    ms_all = []
    step = step_factor * min(pm.voxel_size for pm in media) if media else 1.0
    solid, fog = split_fog(media)
    fog_st = None if fog is None else fog.sigma_t
    delta_of = {id(pm): d for pm, d in zip(media, delta)}
    solid_delta = [delta_of[id(pm)] for pm in solid]
    fog_delta = None if fog is None else delta_of[id(fog)].sigma_t
    shadowed = surfaces is not None and not surfaces.empty
    around = Surroundings(solid, fog_st, surfaces, step, bool(surface_bounce),
                          tuning.disc_exact, tuning.disc_voxels)
    # the traced paths' lattice of each medium, finer round a lamp inside it
    path_res = [lamp_resolution(pm, lights, multiple_resolution, tuning.core_refine)
                for pm in media]
    # traced paths fly through every medium whose box overlaps theirs and deposit on it too
    # (precompute.lightpaths.overlapping); what one medium's paths leave on another's lattice
    # is added to that medium's M once every medium is traced
    partners_of = overlapping(media) if camera is not None else [[] for _ in media]
    partner_lats = {}

    def partners(mi, of=None):
        """(index, PathLattice) of the media medium mi's paths fly through: ``of`` (indices),
        by default those whose boxes overlap its own."""
        got = []
        for j in (partners_of[mi] if of is None else of):
            if j not in partner_lats:
                partner_lats[j] = partner_lattice(media[j], camera, path_res[j], around,
                                                  tuning.path_deposits, tuning.path_nodal)
            if partner_lats[j] is not None:
                got.append((j, partner_lats[j]))
        return got

    crossed = {}   # (medium, light) -> M (and moments) deposited there by other media's paths
    glowed = []    # (medium, stride, E1, Em): other media's glow scattered in that medium
    own_glow = [None] * len(media)       # (stride, E1, Em): a medium's glow in itself
    glow_moments = [None] * len(media)   # (stride, h, moments): the same for the gathers
    lost = []      # (medium, stride, D): the media's absorption of the sky (skydeficit.py)
    # the absorption's share of the sky's multiply scattered light is traced (skydeficit.py):
    # with multiple scattering, a camera, and no world fog (which hides the sky)
    deficit = bool(multiple and camera is not None and fog is None and world_lit
                   and layout.ambient_multiple_channel is not None)
    absorbing = []       # the media whose absorption of the sky is traced (after the lights)
    started = [0.0, 0]   # the lights' paths in all media: their starts' power (W), number
    fields = []
    n_pts = 0
    n_ambient = 0
    n_glow = 0
    n_disc = 0     # lattice points whose lamp's disc was marched (discdepth.py)
    for mi, pm in enumerate(media):
        cm = layout.medium_channels(mi)
        f = np.zeros(pm.grid.shape + (cm,), np.float32)
        f[..., 0] = pm.grid
        for first, grid in layout.own_grids(pm, mi):
            f[..., first:first + 3] = grid
        flat = needed_flat(pm)
        n_pts += len(flat)
        pts = grid_points(pm, flat) if shadowed or fog is not None else None
        view = f.reshape(-1, cm)
        sharp = None
        if layout.beam_channels is not None:   # the medium's mean sigma_s, for peak_light
            rho = density_from(pm.grid.reshape(-1)[flat], pm.threshold)
            occ = rho[rho > 0]
            mean_ss = float(np.mean(pm.sigma_s)) * (float(occ.mean()) if occ.size else 0.0)
        for li, light in enumerate(lights):
            if chans[li] is None:
                continue
            if progress:
                progress(0.0, f"Light attenuation: {light.name} on {pm.medium.name}")
            # the unscattered beam through the media, then (multiple scattering with a forward
            # peak) the beam of unscattered and forward-scattered light: the same optical depth
            # through the delta-scaled media, the surfaces as opaque
            for ch, through, own, through_fog in ((chans[li], solid, pm, fog_st),
                                                  (beams[li], solid_delta, delta[mi], fog_delta)):
                if ch is None:
                    continue
                swept = False
                if pm is not fog:
                    if sharp is None and (own.sharp or any(m.sharp for m in through)):
                        # the same voxels for every light and for the delta-scaled media
                        sharp = near_sharp_surfaces(own, through)
                    swept = sweep_light(through, own, light, f, ch, step, surfaces=surfaces,
                                        threads=threads, should_cancel=should_cancel,
                                        needed=None if pts is None else (flat, pts),
                                        fog_sigma_t=through_fog, sharp=sharp, tuning=tuning)
                if not swept:  # the fog, or not sweepable: march from every needed voxel
                    pts = grid_points(pm, flat) if pts is None else pts
                    tau = light_optical_depth(through, light, pts, step,
                                              should_cancel=should_cancel,
                                              surfaces=None if pm is fog else surfaces,
                                              threads=threads, fog_sigma_t=through_fog,
                                              tuning=tuning)
                    if pm is fog and shadowed:
                        vis = soft_visibility(surfaces, light, pm, flat, pts, threads=threads,
                                              should_cancel=should_cancel)
                        tau = tau - np.log(np.maximum(vis, np.exp(-SHADOW_TAU)))[:, None]
                    view[flat, ch:ch + 3] = tau
            if discs[li] is not None and pm is not fog and solid:
                # the lamp's disc or emitter beyond the march's reach (discdepth.py)
                if progress:
                    progress(0.0, f"Light attenuation: {light.name}'s disc on {pm.medium.name}")
                n_disc += fold_disc(pm, f, chans[li], discs[li], light, around.solid_depth(),
                                    tuning.disc_fold_stride, tuning.disc_fold_nodes,
                                    threads, should_cancel)
            if beams[li] is not None:
                # the beam channels: from the beam's optical depth to the forward peak's own
                # light, spread sideways (W/m^2)
                peak = peak_light(pm, f, light, chans[li], beams[li], mean_ss, flat, step,
                                  multiple_resolution, should_cancel, fog=pm is fog,
                                  tuning=tuning)
                kernels.upsample_into(f, beams[li], peak[0], peak[1], flat)
        own_deficit = False
        if layout.ambient_channel is not None and world_lit:
            # a medium too dense for paths keeps the collided model (none are traced in it)
            own_deficit = deficit and not too_dense(pm, path_res[mi], tuning.path_deposits)
            if progress:
                progress(0.0, f"World light on {pm.medium.name}")
            got = fill_world_light(f, (layout.ambient_channel, layout.ambient_multiple_channel),
                                   solid, pm, world, camera, flat, n_dirs, 2.0 * step,
                                   seed=seed + mi, should_cancel=should_cancel,
                                   surfaces=surfaces, threads=threads, tuning=tuning,
                                   deficit=own_deficit,
                                   ground=bool(surface_bounce) if own_deficit else None)
            n_ambient += got
        if glow and layout.ambient_channel is not None and \
                (pm.glows if pm.endless else pm.emits):
            if progress:
                progress(0.0, f"Emitted light on {pm.medium.name}")
            # a glow lights every medium that scatters, apart from it or overlapping it (the
            # world fog's own glow is fogglow.py's)
            near = [] if pm.endless or camera is None else partners(mi, lit_by_glow(media, mi))
            got = emission_light(pm, camera, multiple_paths if multiple_paths > 0
                                 else EMISSION_PATHS, path_res[mi], multiple,
                                 seed=seed + 7919 * mi + 6007, threads=threads,
                                 should_cancel=should_cancel, around=around,
                                 partners=[(media[j], lat) for j, lat in near],
                                 deposits=tuning.path_deposits,
                                 nodal=tuning.path_nodal, lobe_window=tuning.lobe_window,
                                 gathered=layout.gather_ambient_channel is not None)
            if got is not None:
                stride, once, more, cross, moments = got
                glowed += [(j, lat.stride) + em for (j, lat), em in zip(near, cross)]
                add_glow(f, layout, stride, once, more, flat)
                n_glow += 1
                if moments is not None:
                    own_glow[mi] = (stride, once, more)
                    glow_moments[mi] = (stride, stride * pm.voxel_size, moments)
        if glow and layout.ambient_channel is not None and fog is not None and fog.glows \
                and pm is not fog and camera is not None and np.any(pm.sigma_s > 0):
            # the world fog's glow lights this medium too (precompute.fogglow.glow_on_medium)
            stride, once, more = glow_on_medium(fog, solid, pm, camera, n_dirs, 2.0 * step,
                                                multiple, seed=seed + mi + 4001,
                                                surfaces=surfaces, threads=threads,
                                                should_cancel=should_cancel, tuning=tuning)
            add_glow(f, layout, stride, once, more, flat)
        if own_deficit:
            absorbing.append(mi)
        fields.append(f)
    for li, light in enumerate(lights):
        if discs[li] is not None and not disc_changes(fields, discs[li]):
            around.skip_disc(light)   # no medium uneven across it: the stretch is exact
    # the lights' paths once every medium's light is known: a light's paths weigh the same in
    # media that overlap (lightpaths.across_media), which needs the power of each one's
    # starts first; a medium apart from the others takes the whole Paths setting
    shares = path_shares(media, fields, lights, chans, path_res, around, tuning,
                         partners_of, seed, discs) if traces and multiple else None
    for mi, pm in enumerate(media):
        f = fields[mi]
        ms = [None] * len(lights)
        if multiple and np.any(pm.sigma_s > 0):
            for li, light in enumerate(lights):
                if chans[li] is None:
                    continue
                if progress:
                    stage = "Light paths" if multiple_paths > 0 else "Light pyramid"
                    progress(0.0, f"{stage}: {light.name} on {pm.medium.name}")
                traced = None
                if traces:
                    # light paths traced from the first scatterings (precompute.lightpaths)
                    near = partners(mi)
                    n_li = multiple_paths if shares is None else \
                        max(1, int(np.ceil(multiple_paths * shares[li][mi])))
                    traced = traced_multiple(pm, f, light, chans[li], camera, n_li,
                                             path_res[mi], seed=path_seed(seed, mi, li),
                                             threads=threads, should_cancel=should_cancel,
                                             around=around, moments=tuning.gather_moments,
                                             partners=[(media[j], lat) for j, lat in near],
                                             deposits=tuning.path_deposits,
                                             nodal=tuning.path_nodal,
                                             far_resolution=multiple_resolution,
                                             cell_tau=tuning.cell_tau,
                                             cell_walk=tuning.cell_walk,
                                             lobe_window=tuning.lobe_window,
                                             disc_channel=discs[li],
                                             roulette_floor=tuning.camera_roulette)
                    if traced is not None:
                        for (j, _), m in zip(near, traced[5]):
                            key = (j, li)
                            crossed[key] = m if key not in crossed else crossed[key] + m
                if traced is not None:
                    ms[li] = MultipleField(traced[0], traced[1], [traced[2]], traced=True,
                                           far=traced[3], moments=traced[4])
                    started = [started[0] + traced[6][0], started[1] + traced[6][1]]
                    check(should_cancel)
                    continue
                # the walk starts where the beam of unscattered and forward-scattered light
                # first scatters out of the forward peak (docs/method.md, "The forward peak");
                # without beam channels (paths asked for, the medium too dense for them) from
                # the whole first scattering: the medium itself, unsplit
                walker = delta[mi] if beams[li] is not None else pm
                ms[li] = multiple_field(walker, f, light, chans[li], camera, beam=beams[li],
                                        resolution=multiple_resolution,
                                        should_cancel=should_cancel, g_last=float(pm.g),
                                        threads=threads, tuning=tuning)
                check(should_cancel)
        if camera is not None and any(m is not None and m.flat for m in ms) \
                and not any(m is not None and m.traced for m in ms):
            # a mesh volume's pyramids summed towards the camera, once (precompute.flatten)
            ms = flattened(pm, ms, lights, camera, tuning)
        ms_all.append(ms)
    for mi in absorbing:
        # after every medium's lights' paths: the deficit's paths take their mean weight
        pm = media[mi]
        if progress:
            progress(0.0, f"Sky light absorbed in {pm.medium.name}")
        near = partners(mi, lit_by_glow(media, mi))
        n_lost = deficit_paths(multiple_paths, EMISSION_PATHS, tuning.sky_deficit_paths)
        got = sky_deficit(pm, world.color, camera, n_lost, path_res[mi],
                          seed=seed + 7919 * mi + 3001, threads=threads,
                          should_cancel=should_cancel, around=around,
                          partners=[(media[j], lat) for j, lat in near],
                          surfaces=surfaces, n_dirs=n_dirs,
                          setting=max(int(multiple_paths), n_lost), tuning=tuning,
                          path_weight=started[0] / started[1] if started[1] else None,
                          ground=True)
        if got is not None:
            stride, own, cross = got
            lost.append((mi, stride, own))
            lost += [(j, lat.stride, d) for (j, lat), d in zip(near, cross)]
    for j, stride, once, more in glowed:
        if layout.ambient_channel is None:
            continue
        add_glow(fields[j], layout, stride, once, more, needed_flat(media[j]))
    for j, stride, d in lost:
        add_lattice(fields[j], layout.ambient_multiple_channel, -d, stride,
                    needed_flat(media[j]))
    if layout.gather_ambient_channel is not None:
        # the gathers' world light: the same less each medium's own glow (its moments stand
        # for it; march.MarchContext.for_gathers)
        for j, f in enumerate(fields):
            gather_world_light(f, layout, own_glow[j], needed_flat(media[j]))
    for (j, li), m in crossed.items():
        mf = ms_all[j][li]
        if mf is None or not mf.traced:   # a medium without paths of its own (too dense)
            continue
        mf.levels[0] = mf.levels[0] + m[..., :3]
        if mf.moments is not None and m.shape[-1] > 3:
            mf.moments = mf.moments + m[..., 3:]
    return Precomputed(fields, layout, ms_all, time.perf_counter() - t_start,
                       {"points": n_pts, "ambient_points": n_ambient,
                        "backend": kernels.backend(), "glowing": n_glow,
                        "disc_points": n_disc},
                       glow_moments if any(g is not None for g in glow_moments) else None)


def gather_world_light(f: np.ndarray, layout: FieldLayout, glow, flat: np.ndarray) -> None:
    """Fill ``f``'s gather world-light channels (FieldLayout.gather_ambient_channel, the
    single and multiply scattered parts) at the voxels ``flat``: its world light's channels
    less the medium's own glow ``glow`` = (stride, E1, Em) (None: nothing to take off), not
    below 0 (float32 rounding where the glow is all of it)."""
    view = f.reshape(-1, f.shape[-1])
    for src, dst in ((layout.ambient_channel, layout.gather_ambient_channel),
                     (layout.ambient_multiple_channel, layout.gather_ambient_multiple_channel)):
        view[flat, dst:dst + 3] = view[flat, src:src + 3]
    if glow is None:
        return
    stride, once, more = glow
    for lat, dst in ((once, layout.gather_ambient_channel),
                     (more, layout.gather_ambient_multiple_channel)):
        if lat is not None:
            add_lattice(f, dst, -lat, stride, flat)
            view[flat, dst:dst + 3] = np.maximum(view[flat, dst:dst + 3], 0.0)


def path_seed(seed: int, mi: int, li: int) -> int:
    """The seed of light ``li``'s paths in medium ``mi`` (their starts' draws and the
    trace's)."""
    return seed + 7919 * mi + li


def path_shares(media, fields, lights, chans, path_res, around, tuning: Tuning, partners_of,
                seed: int, discs=None):
    """[light][medium] the share of the Paths setting each medium's paths for each light
    take: the power of its paths' starts (lightpaths.start_power: the first scatterings and
    the light the surfaces reflect into it, as traced_multiple will start them with the same
    seeds, ``path_seed``) over the most among it and the media
    whose boxes overlap its own (``partners_of``, whose lattices its paths deposit on, and
    theirs on its own; lightpaths.across_media).  1 for a medium apart from the others, the
    world fog (whose paths also start beyond its grid) and a light without paths; None
    where no two scattering media overlap.  ``discs``: the lights' disc channels
    (FieldLayout.disc_channels) or None."""
    discs = discs or [None] * len(lights)
    live = [mi for mi, pm in enumerate(media)
            if np.any(pm.sigma_s > 0) and not pm.endless and
            any(np.any(media[j].sigma_s > 0) and not media[j].endless for j in partners_of[mi])]
    if not live:
        return None
    shares = []
    for li, light in enumerate(lights):
        share = [1.0] * len(media)
        if chans[li] is not None:
            power = {mi: start_power(media[mi], fields[mi], light, chans[li], path_res[mi],
                                     around, tuning.cell_tau, tuning.cell_walk,
                                     seed=path_seed(seed, mi, li),
                                     disc_channel=discs[li])
                     for mi in live}
            for mi in live:
                group = [mi] + [j for j in partners_of[mi] if j in power]
                share[mi] = across_media([power[j] for j in group])[0]
        shares.append(share)
    return shares
