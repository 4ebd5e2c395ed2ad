"""The light record: the one layout of a light as the kernels read it.

One float64 row of ``LIGHT_FIELDS`` per light (lights.pack_light writes it; the march, the
optical-depth sweeps and light_sample, C and numpy, read it).  The offsets below are the only
definition: the compiled kernels carry the same values in ``mpp_render/csrc/light.h`` and
export them as ``_kernels.light_layout()``, which tests/test_kernels.py holds to this module.
This module imports nothing, so that the build, the tests and every stage can read it.

Fields (offset: width; units):
  L_KIND 0: 1       the light's kind, one of KIND_*
  L_STRENGTH 1: 3   scene.Light.strength (RGB: W for a point, spot or area light; the sun's
                    irradiance, W/m^2)
  L_POS 4: 3        centre (m, world)
  L_DIR 7: 3        direction of propagation (unit, world; the sun's)
  L_INV 10: 9       inverse of the light's 3x3 matrix, row-major (world -> the light's frame,
                    non-uniform scale included: a spot's cone is measured there)
  L_COSHALF 19: 1   cosine of a spot's half angle
  L_BLEND 20: 1     a spot's blend (0: hard edge)
  L_RADIUS 21: 1    a point's or spot's radius (m; 0: a point)
  L_AX 22, L_AY 25: 3 each  an area light's axes (m, world; lights.area_geometry)
  L_AREA 28: 1      an area light's area (m^2)
  L_NORMAL 29: 3    an area light's emitting normal (unit, world)
  L_NORMALIZE 32: 1 1: the area light's power is spread over its area
  L_ROUND 33: 1     1: a round (disc or ellipse) area light
  L_CHANNEL 34: 1   its optical-depth channel in the media fields, or -1: not lit
  L_COND 35: 1      condition number of the spot's inverse matrix (how much it can widen angles)
  L_BEAM 36: 1      the channel of its forward-peak light (W/m^2) in the fields, or < 1: none
                    (precompute.FieldLayout.beam_channels; read with multiple scattering only)
  L_INDIRECT 37: 1  1: scattered light (scene.Light.indirect): its single scattering is added
                    to the multiple output
  L_DISC 38: 1      the channel of its disc's depth change beyond the march's reach (a point
                    or spot light with a radius; precompute.FieldLayout.disc_channels,
                    precompute/discdepth.py), or < 1: none
  L_ANGLES 39: 2    a spot's half angle and the inner angle where its blend begins (rad; the
                    half angle where it has no blend), the two angles of its light_sample's
                    one-point test, worked out once
"""

LIGHT_FIELDS = 41
L_KIND, L_STRENGTH, L_POS, L_DIR, L_INV, L_COSHALF, L_BLEND, L_RADIUS = 0, 1, 4, 7, 10, 19, 20, 21
L_AX, L_AY, L_AREA, L_NORMAL, L_NORMALIZE, L_ROUND, L_CHANNEL = 22, 25, 28, 29, 32, 33, 34
L_COND, L_BEAM, L_INDIRECT, L_DISC, L_ANGLES = 35, 36, 37, 38, 39

KIND_POINT, KIND_SPOT, KIND_SUN, KIND_AREA = 0, 1, 2, 3


def layout() -> dict:
    """Every L_* offset, LIGHT_FIELDS and every KIND_*: the form _kernels.light_layout() has."""
    return {k: v for k, v in globals().items()
            if k == "LIGHT_FIELDS" or k.startswith(("L_", "KIND_"))}
