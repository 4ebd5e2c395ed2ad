"""The render passes the engine fills, with their channel layout.

Every pass is an array (height, width, channels) of float32 with row 0 at the top.
Blender wants row 0 at the bottom: the glue flips when it writes a render result.

* ``Combined`` (RGBA): background seen through the media + single + multiple scattering
  + emission; alpha is 1, or 1 - mean(Transmittance) when the film is transparent.
* ``Volume Single`` (RGB): light scattered exactly once in the media (W/(m^2 sr)).
* ``Volume Multiple`` (RGB): light scattered more than once, from the MPP approximation.
* ``Emission`` (RGB): light the media emit (Principled Volume emission), seen through them.
* ``Transmittance`` (RGB): transmittance of the camera ray through all media, in [0, 1].
* ``Depth`` (Z): axial distance in metres (along the camera's -Z, like Cycles' Depth pass) to
  the first point where the ray's opacity 1 - mean(T) reaches ``DEPTH_OPACITY``; 1e10 where it
  never does (Cycles' value for rays that hit nothing).
"""
from __future__ import annotations

from dataclasses import dataclass

DEPTH_OPACITY = 0.01
DEPTH_MISS = 1.0e10


@dataclass(frozen=True)
class PassInfo:
    name: str
    channels: int
    chan_id: str  # Blender's channel letters, e.g. "RGBA", "RGB", "Z"
    kind: str  # Blender's pass type: 'COLOR' or 'VALUE'


PASSES = (
    PassInfo("Combined", 4, "RGBA", "COLOR"),
    PassInfo("Volume Single", 3, "RGB", "COLOR"),
    PassInfo("Volume Multiple", 3, "RGB", "COLOR"),
    PassInfo("Emission", 3, "RGB", "COLOR"),
    PassInfo("Transmittance", 3, "RGB", "COLOR"),
    PassInfo("Depth", 1, "Z", "VALUE"),
)

PASS_BY_NAME = {p.name: p for p in PASSES}


def enabled_passes(multiple: bool, requested=None):
    """Passes the engine fills for these settings: ``Volume Multiple`` only when multiple
    scattering is on; ``requested`` (names) narrows the list, Combined is always kept."""
    out = []
    for p in PASSES:
        if p.name == "Volume Multiple" and not multiple:
            continue
        if requested is not None and p.name != "Combined" and p.name not in requested:
            continue
        out.append(p)
    return out
