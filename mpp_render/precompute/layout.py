"""The channel layout of a medium's field array (X, Y, Z, C) float32, defined here once:
the precompute fills it, the cache patches its parts, the march reads it.

In order: channel 0 the density; per lit light 3 channels of RGB optical depth to it; with
multiple scattering in a forward-scattering medium per lit light 3 channels of its forward
peak's light; per point or spot light with a radius or area light (``lights.has_extent``) 3
channels of its disc's (emitter's) depth change beyond the march's reach
(precompute/discdepth.py); with a lit world or
a medium's emission that lights a medium that scatters (media.glow_lights) 3 channels of
world light, then with multiple scattering 3 of its multiply scattered part (the glow's
light scattered once and more is added to them, precompute.emissionlight), then where the
surfaces' gathers read a glow from its paths' moments (``glow_gathered``) 3 + 3 channels of
the same without each medium's own glow; then, for a medium with
an emission grid only, 3 channels of its emitted radiance; then, for a medium with a scatter
colour grid only (PreparedMedium.scatter_grid), 3 channels of its factor on sigma_s; last,
for a medium whose extinction's colour varies only (PreparedMedium.extinction_density), 3
channels of the density each channel's extinction reads.  The world's, the emission's, the
scatter colour's and the extinction's channels run to the end of the field
(``world_first``).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

from ..lights import has_extent, is_dark
from ..media import PreparedMedium, delta_scaled, glow_lights


@dataclass
class FieldLayout:
    """Channel offsets in a medium's field array.  ``light_channels[i]`` is the offset of
    light i's optical depth, or None when the light is skipped (dark).  ``channels``: the
    channels every medium's field has; ``emission_channels[m]``: the offset of medium m's
    emission grid (its field then has ``channels + 3``), or None; ``scatter_channels[m]``:
    that of its scatter colour grid (3 more channels, after the emission's), or None;
    ``extinction_channels[m]``: that of its extinction density (3 more, after those), or None.
    ``beam_channels[i]``
    (multiple scattering on, some medium with a forward peak): the offset of light i's
    forward peak's light (W/m^2, ``peak_light``: what has scattered into the peak and not
    out of it, spread sideways), first the optical depth through the delta-scaled media
    (media.delta_scaled) from which it is made; right after the lights' channels.
    ``disc_channels[i]`` (a point or spot light with a radius or an area light,
    ``lights.has_extent``): the offset of light i's disc's (emitter's) optical-depth change
    beyond the march's reach (discdepth.py), after the beams' channels, before the world's.
    ``gather_ambient_channel`` and ``gather_ambient_multiple_channel`` (a medium's glow whose
    traced paths keep their moments for the surfaces' gathers, precompute.emissionlight):
    3 + 3 channels right after the world light's, holding the same but for each medium's own
    glow, which the gathers read from its moments instead (``for_gathers``)."""

    light_channels: List[Optional[int]]
    ambient_channel: Optional[int]
    channels: int
    ambient_multiple_channel: Optional[int] = None
    emission_channels: Optional[List[Optional[int]]] = None
    beam_channels: Optional[List[Optional[int]]] = None
    scatter_channels: Optional[List[Optional[int]]] = None
    extinction_channels: Optional[List[Optional[int]]] = None
    disc_channels: Optional[List[Optional[int]]] = None
    gather_ambient_channel: Optional[int] = None
    gather_ambient_multiple_channel: Optional[int] = None

    def for_gathers(self, extra_lights: int = 0) -> "FieldLayout":
        """The layout as the surfaces' gathers read it: the world light's channels without
        the media's own glow (``gather_ambient_channel``; the layout itself where there are
        none), and ``extra_lights`` more lights without channels after the others (the
        glow's moments' slot, march.MarchContext.for_gathers)."""
        if self.gather_ambient_channel is None and not extra_lights:
            return self
        def more(chans):
            return None if chans is None else list(chans) + [None] * extra_lights
        out = dataclasses.replace(self, light_channels=more(self.light_channels),
                                  beam_channels=more(self.beam_channels),
                                  disc_channels=more(self.disc_channels))
        if self.gather_ambient_channel is not None:
            out = dataclasses.replace(out, ambient_channel=self.gather_ambient_channel,
                                      ambient_multiple_channel=self.gather_ambient_multiple_channel)
        return out

    def own_grids(self, pm: PreparedMedium, m: int):
        """(first channel, grid) of each of medium ``pm``'s own grids (index ``m``) in its
        field: emission, scatter colour, extinction density."""
        out = []
        for chans, grid in ((self.emission_channels, pm.emission_grid),
                            (self.scatter_channels, pm.scatter_grid),
                            (self.extinction_channels, pm.extinction_density)):
            if chans is not None and chans[m] is not None:
                out.append((chans[m], grid))
        return out

    def medium_channels(self, m: int) -> int:
        """The channels of medium m's field: ``channels`` and its own grids' after them."""
        return self.channels + 3 * sum(
            ch is not None and ch[m] is not None
            for ch in (self.emission_channels, self.scatter_channels,
                       self.extinction_channels))

    @property
    def world_first(self) -> Optional[int]:
        """The first world-light channel (the world's and the emission's run to the end of
        the field), or None with an unlit world."""
        return self.ambient_channel


def light_channels(lights) -> List[Optional[int]]:
    """The optical-depth channel of each light (None for a dark light): 1, 4, 7, ..."""
    out, c = [], 1
    for light in lights:
        if is_dark(light):
            out.append(None)
        else:
            out.append(c)
            c += 3
    return out


def field_layout(media: Sequence[PreparedMedium], lights, world_color, multiple: bool,
                 delta: Optional[Sequence[PreparedMedium]] = None,
                 peak: bool = True, glow: bool = True, disc: bool = True,
                 gather_glow: bool = False) -> FieldLayout:
    """The layout of the fields the precompute gives ``media`` lit by ``lights`` and a world
    of colour ``world_color``, with or without ``multiple`` scattering.  ``delta``: the
    media delta-scaled (media.delta_scaled), where the caller has them.  ``peak``: whether
    multiple scattering carries the forward peak's light apart (the walk's beam channels,
    precompute.source.peak_light); traced paths (paths.py) carry it themselves.  ``glow``:
    whether the media's glow counts as world light (the cache's part without the world
    sets it False).  ``disc``: whether the lamps' discs are folded (Tuning.disc_fold_stride
    > 0; ``lights.has_extent``).  ``gather_glow``: the surfaces' gathers read the media's own
    glow from its paths' moments (``glow_gathered``), so the world light is kept a second
    time without it (FieldLayout.gather_ambient_channel)."""
    chans = light_channels(lights)
    c = 1 + 3 * sum(ch is not None for ch in chans)
    beams = [None] * len(lights)
    delta = [delta_scaled(pm) for pm in media] if delta is None else delta
    if multiple and peak and any(d is not pm for d, pm in zip(delta, media)):
        for i in range(len(lights)):
            if chans[i] is not None:
                beams[i] = c
                c += 3
    discs = [None] * len(lights)
    for i, light in enumerate(lights):
        if disc and chans[i] is not None and has_extent(light):
            discs[i] = c
            c += 3
    lit = np.any(np.asarray(world_color) > 0) or (glow and glow_lights(media))
    amb = c if lit else None
    amb_ms = None
    if amb is not None:
        c += 3
        if multiple:
            amb_ms = c
            c += 3
    g_amb = g_ms = None
    if amb is not None and amb_ms is not None and gather_glow:
        g_amb, g_ms = c, c + 3
        c += 6
    own = [[pm.emission_grid is not None, pm.scatter_grid is not None,
            pm.extinction_density is not None] for pm in media]
    firsts = [[c + 3 * sum(has[:k]) if has[k] else None for k in range(3)] for has in own]
    emission, scatter, extinction = ([f[k] for f in firsts] for k in range(3))
    return FieldLayout(chans, amb, c, amb_ms, emission,
                       beams if any(b is not None for b in beams) else None, scatter,
                       extinction, discs if any(k is not None for k in discs) else None,
                       g_amb, g_ms)


def glow_gathered(media: Sequence[PreparedMedium], traced: bool, surfaces, moments: bool,
                  glow: bool = True) -> bool:
    """Whether the surfaces' gathers read the media's glow from its traced paths' moments
    (precompute.emissionlight): the glow counts (``glow``), some medium other than the
    world's fog emits into a medium that scatters, the paths are traced (``traced``: multiple
    scattering by traced paths, a camera), surfaces gather (``surfaces`` not empty) and their
    gathers read moments (Tuning.gather_moments)."""
    return bool(glow and traced and moments and surfaces is not None and not surfaces.empty
                and glow_lights(list(media))
                and any(pm.emits and not pm.endless for pm in media))
