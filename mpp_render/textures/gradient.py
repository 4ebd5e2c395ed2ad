"""Blender's Gradient Texture node, vectorised over points with numpy.

Follows Cycles ``intern/cycles/kernel/svm/gradient.h`` (``svm_gradient``) and the Geometry
Nodes multi-function of ``source/blender/nodes/shader/nodes/node_shader_tex_gradient.cc``
(Blender 4.2-5.0), written again here in numpy.

Conventions: ``vector`` is an (N, 3) array of texture coordinates (a single (3,) vector is
taken as N = 1); every value is computed in float32 as Blender does and returned as float32.
The node clamps the factor to [0, 1] (Cycles' ``saturatef``; Geometry Nodes in Blender 5.0
too, checked); ``clamp=False`` gives the raw gradient (Linear, Quadratic and Diagonal
exceed [0, 1]; the other types stay inside it).
"""
import numpy as np

GRADIENT_TYPES = ("LINEAR", "QUADRATIC", "EASING", "DIAGONAL", "RADIAL",
                  "QUADRATIC_SPHERE", "SPHERICAL")

# Cycles biases the spheres a little so a unit-length vector gives exactly 0.
_SPHERE_BIAS = np.float32(0.999999)


def _as_points(vector):
    v = np.asarray(vector, dtype=np.float32)
    if v.ndim == 1:
        v = v[None, :]
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vector must be (N, 3), got {v.shape}")
    return v


def gradient_texture(vector, gradient_type="LINEAR", clamp=True):
    """The node's Fac output, (N,) float32.

    gradient_type: one of GRADIENT_TYPES (Blender's enum identifiers).  clamp: saturate to
    [0, 1] as the node does (False: the raw gradient)."""
    v = _as_points(vector)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    f32 = np.float32
    if gradient_type == "LINEAR":
        fac = x.copy()
    elif gradient_type == "QUADRATIC":
        r = np.maximum(x, f32(0.0))
        fac = r * r
    elif gradient_type == "EASING":
        r = np.clip(x, f32(0.0), f32(1.0))
        t = r * r
        fac = f32(3.0) * t - f32(2.0) * t * r
    elif gradient_type == "DIAGONAL":
        fac = (x + y) * f32(0.5)
    elif gradient_type == "RADIAL":
        fac = np.arctan2(y, x) / f32(2.0 * np.pi) + f32(0.5)
    elif gradient_type in ("QUADRATIC_SPHERE", "SPHERICAL"):
        length = np.sqrt(x * x + y * y + z * z)
        r = np.maximum(_SPHERE_BIAS - length, f32(0.0))
        fac = r * r if gradient_type == "QUADRATIC_SPHERE" else r
    else:
        raise ValueError(f"unknown gradient_type {gradient_type!r}; one of {GRADIENT_TYPES}")
    fac = fac.astype(np.float32, copy=False)
    if clamp:
        fac = np.clip(fac, f32(0.0), f32(1.0))
    return fac


def gradient_color(fac):
    """The node's Color output from its Fac: fac as grey, (N, 3) float32."""
    fac = np.asarray(fac, dtype=np.float32)
    return np.repeat(fac[:, None], 3, axis=1)


def gradient_outputs(vector, gradient_type="LINEAR", clamp=True):
    """Both outputs by socket name: {'Fac': (N,), 'Color': (N, 3)}."""
    fac = gradient_texture(vector, gradient_type, clamp)
    return {"Fac": fac, "Color": gradient_color(fac)}
