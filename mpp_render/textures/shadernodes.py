"""Blender's shader nodes evaluated on arrays of points (no bpy).

One function per node kind, registered in ``KINDS`` with the outputs it gives and what of
the points it reads.  Each follows the Cycles SVM node named in its docstring
(``intern/cycles/kernel/svm/``); Math, Vector Math and the colour operations live in
``mathops.py`` and ``colour.py``; the textures call ``noise.py``, ``voronoi.py``,
``gradient.py`` and ``wave.py``.  :func:`unsupported` says why a node (or one of its
outputs) cannot be evaluated, so the glue can replace it by its input's value and warn.

Each function takes the evaluation context (``graph._Context``: its inputs read as
``ctx.value`` / ``ctx.vector`` / ``ctx.colour`` with the link conversions of sockets.py,
``ctx.param`` for the textures, ``ctx.points``) and returns its outputs by identifier.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable, Dict, Optional, Set, Tuple

import numpy as np

from . import colour as col
from . import mathops
from .sockets import RGBA, VALUE, VECTOR, convert

CONVERT = "mpp.Convert"      # a conversion the glue inserts where a group socket changes type

Outputs = Dict[str, Tuple[np.ndarray, str]]


@dataclass(frozen=True)
class NodeKind:
    """How one kind of node evaluates.  ``run(ctx, node, wanted)`` returns its outputs by
    identifier as (values, socket type) (``wanted``: the outputs some link reads);
    ``outputs``: the identifiers it gives (None: all of the node's); ``reads(node,
    output)``: what of the points the output reads ('position', 'generated', 'object',
    'attribute:<name>'); ``check(node)``: why these settings cannot be evaluated (a phrase
    following the node's name: 'is not supported with ...'), or None."""

    run: Callable[[object, object, Set[str]], Outputs]
    outputs: Optional[Tuple[str, ...]] = None
    reads: Optional[Callable[[object, str], Set[str]]] = None
    check: Optional[Callable[[object], Optional[str]]] = None


KINDS: Dict[str, NodeKind] = {}


def _kind(*names, outputs=None, reads=None, check=None):
    def register(fn):
        for name in names:
            KINDS[name] = NodeKind(fn, outputs, reads, check)
        return fn
    return register


def unsupported(node, output: Optional[str] = None) -> Optional[str]:
    """Why ``node`` (or its output ``output``) cannot be evaluated here -- a phrase that
    follows the node's name ('is not supported', 'is not supported through its output
    ...') -- or None."""
    kind = KINDS.get(node.kind)
    if kind is None:
        return "is not supported"
    if output is not None and kind.outputs is not None and output not in kind.outputs:
        return f"is not supported through its output '{output}'"
    return kind.check(node) if kind.check is not None else None



# -- inputs, constants, conversions ---------------------------------------------------------

@_kind("ShaderNodeValue", outputs=("Value",))
def _value(ctx, node, wanted):
    """The Value node: ``props['value']``."""
    return {"Value": (np.full(ctx.n, float(node.props.get("value", 0.0))), VALUE)}


@_kind("ShaderNodeRGB", outputs=("Color",))
def _rgb(ctx, node, wanted):
    """The RGB node: ``props['color']`` (RGBA; alpha dropped)."""
    c = node.props.get("color", (0.5, 0.5, 0.5, 1.0))
    return {"Color": (np.tile(np.asarray(c, np.float64)[:3], (ctx.n, 1)), RGBA)}


@_kind(CONVERT, outputs=("Value",))
def _convert(ctx, node, wanted):
    """A socket of another type on the way (a group's interface, a reroute): input 'Value'
    converted to ``props['to']``."""
    to = node.props.get("to", VALUE)
    return {"Value": (convert(*ctx.raw(node, "Value", 0.0), to), to)}


# -- where the point is ---------------------------------------------------------------------

def _texcoord_reads(node, output):
    if output == "Object" and node.props.get("object_matrix") is not None:
        return {"position"}
    return {output.lower()}


@_kind("ShaderNodeTexCoord", outputs=("Generated", "Object"), reads=_texcoord_reads)
def _tex_coord(ctx, node, wanted):
    """Texture Coordinate (Cycles ``svm_node_tex_coord``): 'Generated' (the object's texture
    space; for volumes ``NODE_TEXCO_VOLUME_GENERATED``) and 'Object' (object space; with
    the node's Object set, ``props['object_matrix']``: that object's world -> object 4x4
    as 16 floats, row-major)."""
    out = {}
    if "Generated" in wanted:
        out["Generated"] = (np.asarray(ctx.points.generated, np.float64), VECTOR)
    if "Object" in wanted:
        m = node.props.get("object_matrix")
        if m is None:
            out["Object"] = (np.asarray(ctx.points.object, np.float64), VECTOR)
        else:
            m = np.asarray(m, np.float64).reshape(4, 4)
            out["Object"] = (ctx.points.position @ m[:3, :3].T + m[:3, 3], VECTOR)
    return out


@_kind("ShaderNodeNewGeometry", outputs=("Position",), reads=lambda node, output: {"position"})
def _geometry(ctx, node, wanted):
    """Geometry: 'Position', the shading point in world metres (the other outputs describe
    a surface and are not supported in a volume)."""
    return {"Position": (ctx.points.position, VECTOR)}


# -- grids ----------------------------------------------------------------------------------

def _attribute_outputs(values, n) -> Outputs:
    """Cycles' ``svm_node_attr`` for a volume grid: a scalar grid gives Fac = value, Color =
    Vector = (value, value, value), Alpha 1; a vector / colour grid gives Fac = the mean of
    its components; a missing grid gives 0 everywhere."""
    if values is None:
        zero3 = np.zeros((n, 3))
        return {"Color": (zero3, RGBA), "Vector": (zero3, VECTOR), "Fac": (np.zeros(n), VALUE),
                "Alpha": (np.zeros(n), VALUE)}
    a = np.asarray(values, np.float64)
    if a.ndim == 1:
        v3 = np.repeat(a[:, None], 3, axis=1)
        return {"Color": (v3, RGBA), "Vector": (v3, VECTOR), "Fac": (a, VALUE),
                "Alpha": (np.ones(n), VALUE)}
    alpha = a[:, 3] if a.shape[1] > 3 else np.ones(n)
    v3 = a[:, :3]
    return {"Color": (v3, RGBA), "Vector": (v3, VECTOR), "Fac": (v3.mean(axis=1), VALUE),
            "Alpha": (alpha, VALUE)}


def _attribute_check(node):
    kind = node.props.get("attribute_type", "GEOMETRY")
    return None if kind == "GEOMETRY" else f"is not supported with attribute type {kind}"


@_kind("ShaderNodeAttribute", check=_attribute_check,
       reads=lambda node, output: {"attribute:" + str(node.props.get("attribute_name", ""))})
def _attribute(ctx, node, wanted):
    """Attribute (type Geometry): the grid ``props['attribute_name']`` at the points."""
    name = str(node.props.get("attribute_name", ""))
    return _attribute_outputs(ctx.points.attributes.get(name), ctx.n)


VOLUME_INFO = {"Color": "color", "Density": "density", "Flame": "flame",
               "Temperature": "temperature"}


@_kind("ShaderNodeVolumeInfo", reads=lambda node, output: {"attribute:" + VOLUME_INFO[output]})
def _volume_info(ctx, node, wanted):
    """Volume Info: the grids 'color', 'density', 'flame' and 'temperature' (0 where the
    volume has no such grid, as Cycles)."""
    out = {}
    for socket in wanted:
        grid = _attribute_outputs(ctx.points.attributes.get(VOLUME_INFO[socket]), ctx.n)
        out[socket] = grid["Color"] if socket == "Color" else grid["Fac"]
    return out


# -- vectors --------------------------------------------------------------------------------

def euler_matrix(rotation: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of XYZ Euler angles (N, 3) in radians: Rz Ry Rx, as
    Blender's ``eul_to_mat3`` and Cycles' ``euler_to_transform``."""
    cx, cy, cz = np.cos(rotation).T
    sx, sy, sz = np.sin(rotation).T
    m = np.empty(rotation.shape[:-1] + (3, 3))
    m[..., 0, 0] = cy * cz
    m[..., 0, 1] = sy * sx * cz - cx * sz
    m[..., 0, 2] = sy * cx * cz + sx * sz
    m[..., 1, 0] = cy * sz
    m[..., 1, 1] = sy * sx * sz + cx * cz
    m[..., 1, 2] = sy * cx * sz - sx * cz
    m[..., 2, 0] = -sy
    m[..., 2, 1] = cy * sx
    m[..., 2, 2] = cy * cx
    return m


@_kind("ShaderNodeMapping")
def _mapping(ctx, node, wanted):
    """Mapping (Cycles ``svm_mapping``), by ``vector_type``: POINT R (v S) + L; TEXTURE
    R^T (v - L) / S (0 where S is 0); VECTOR R (v S); NORMAL normalize(R (v / S)); R the
    XYZ Euler rotation of input Rotation (radians), S Scale, L Location."""
    v = ctx.vector(node, "Vector")
    loc = ctx.vector(node, "Location")
    rot = euler_matrix(ctx.vector(node, "Rotation"))
    scale = ctx.vector(node, "Scale", (1.0, 1.0, 1.0))
    kind = node.props.get("vector_type", "POINT")
    if kind == "TEXTURE":
        out = mathops.safe_divide(np.einsum("nji,nj->ni", rot, v - loc), scale)
    elif kind == "NORMAL":
        out = mathops.safe_normalize(np.einsum("nij,nj->ni", rot, mathops.safe_divide(v, scale)))
    else:
        out = np.einsum("nij,nj->ni", rot, v * scale)
        if kind == "POINT":
            out = out + loc
    return {"Vector": (out, VECTOR)}


@_kind("ShaderNodeSeparateXYZ")
def _separate_xyz(ctx, node, wanted):
    v = ctx.vector(node, "Vector")
    return {"X": (v[:, 0], VALUE), "Y": (v[:, 1], VALUE), "Z": (v[:, 2], VALUE)}


@_kind("ShaderNodeCombineXYZ")
def _combine_xyz(ctx, node, wanted):
    v = np.stack([ctx.value(node, k) for k in ("X", "Y", "Z")], axis=1)
    return {"Vector": (v, VECTOR)}


def _vector_math_check(node):
    op = node.props.get("operation", "ADD")
    return None if op in mathops.VECTOR_MATH else f"is not supported with operation {op}"


@_kind("ShaderNodeVectorMath", check=_vector_math_check)
def _vector_math(ctx, node, wanted):
    """Vector Math (``svm_vector_math``; the operations in mathops.VECTOR_MATH): outputs
    'Vector' and 'Value' (the one the operation does not give is 0)."""
    fn, gives = mathops.VECTOR_MATH[node.props.get("operation", "ADD")]
    result = fn(ctx.vector(node, "Vector"), ctx.vector(node, "Vector_001"),
                ctx.vector(node, "Vector_002"), ctx.value(node, "Scale", 1.0))
    if gives == mathops.VALUE:
        return {"Value": (result, VALUE), "Vector": (np.zeros((ctx.n, 3)), VECTOR)}
    return {"Vector": (result, VECTOR), "Value": (np.zeros(ctx.n), VALUE)}


# -- numbers --------------------------------------------------------------------------------

def _math_check(node):
    op = node.props.get("operation", "ADD")
    return None if op in mathops.MATH else f"is not supported with operation {op}"


@_kind("ShaderNodeMath", check=_math_check)
def _math(ctx, node, wanted):
    """Math (``svm_math``; the operations in mathops.MATH), clamped to [0, 1] with
    ``use_clamp``."""
    fn = mathops.MATH[node.props.get("operation", "ADD")]
    out = fn(ctx.value(node, "Value", 0.5), ctx.value(node, "Value_001", 0.5),
             ctx.value(node, "Value_002", 0.0))
    if node.props.get("use_clamp", False):
        out = np.clip(out, 0.0, 1.0)
    return {"Value": (np.asarray(out, np.float64), VALUE)}


def _clamp_range(x, a, b):
    """``x`` clamped between a and b whichever is larger (Clamp's RANGE)."""
    return np.where(a > b, np.clip(x, b, a), np.minimum(np.maximum(x, a), b))


@_kind("ShaderNodeClamp")
def _clamp(ctx, node, wanted):
    """Clamp (``svm_node_clamp``): MINMAX min(max(v, Min), Max); RANGE the same with Min
    and Max swapped where Min > Max."""
    v, lo, hi = ctx.value(node, "Value"), ctx.value(node, "Min"), ctx.value(node, "Max", 1.0)
    if node.props.get("clamp_type", "MINMAX") == "RANGE":
        return {"Result": (_clamp_range(v, lo, hi), VALUE)}
    return {"Result": (np.minimum(np.maximum(v, lo), hi), VALUE)}


def _smoothstep01(t):
    t = np.clip(t, 0.0, 1.0)
    return (3.0 - 2.0 * t) * t * t


def _smootherstep01(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _map_factor(kind, x, lo, hi, steps):
    """The Map Range factor of ``x`` between ``lo`` and ``hi`` (where hi != lo)."""
    f = mathops.safe_divide(x - lo, hi - lo)
    if kind == "STEPPED":
        with np.errstate(all="ignore"):
            stepped = np.floor(f * (steps + 1.0)) / np.where(steps > 0.0, steps, 1.0)
        return np.where(steps > 0.0, stepped, 0.0)
    if kind == "SMOOTHSTEP":
        return _smoothstep01(f)
    if kind == "SMOOTHERSTEP":
        return _smootherstep01(f)
    return f


@_kind("ShaderNodeMapRange")
def _map_range(ctx, node, wanted):
    """Map Range (``svm_node_map_range`` and ``svm_node_vector_map_range``):
    To Min + factor (To Max - To Min), the factor LINEAR (x - From Min) / (From Max -
    From Min), STEPPED floor(f (Steps + 1)) / Steps, SMOOTHSTEP / SMOOTHERSTEP the clamped
    Hermite polynomials; ``clamp`` (LINEAR and STEPPED) keeps the result between To Min and
    To Max.  FLOAT: where From Min = From Max the result is 0, as Cycles (Geometry Nodes
    give To Min there); FLOAT_VECTOR works per component with a factor of 0 there."""
    kind = node.props.get("interpolation_type", "LINEAR")
    clamp = bool(node.props.get("clamp", True)) and kind in ("LINEAR", "STEPPED")
    if node.props.get("data_type", "FLOAT") == "FLOAT_VECTOR":
        x = ctx.vector(node, "Vector")
        lo = ctx.vector(node, "From_Min_FLOAT3")
        hi = ctx.vector(node, "From_Max_FLOAT3", (1.0, 1.0, 1.0))
        to_lo = ctx.vector(node, "To_Min_FLOAT3")
        to_hi = ctx.vector(node, "To_Max_FLOAT3", (1.0, 1.0, 1.0))
        steps = ctx.vector(node, "Steps_FLOAT3", (4.0, 4.0, 4.0))
        out = to_lo + _map_factor(kind, x, lo, hi, steps) * (to_hi - to_lo)
        if clamp:
            out = _clamp_range(out, to_lo, to_hi)
        return {"Vector": (out, VECTOR), "Result": (np.zeros(ctx.n), VALUE)}
    x = ctx.value(node, "Value", 1.0)
    lo, hi = ctx.value(node, "From Min"), ctx.value(node, "From Max", 1.0)
    to_lo, to_hi = ctx.value(node, "To Min"), ctx.value(node, "To Max", 1.0)
    steps = ctx.value(node, "Steps", 4.0)
    # (Cycles' 1 - s(From Max, From Min, x) for a reversed smooth range equals s(factor))
    factor = _map_factor(kind, x, lo, hi, steps)
    out = np.where(hi != lo, to_lo + factor * (to_hi - to_lo), 0.0)
    if clamp:
        out = _clamp_range(out, to_lo, to_hi)
    return {"Result": (out, VALUE), "Vector": (np.zeros((ctx.n, 3)), VECTOR)}


# -- colours --------------------------------------------------------------------------------

@_kind("ShaderNodeValToRGB")
def _color_ramp(ctx, node, wanted):
    """Color Ramp (``BKE_colorband_evaluate``; colour.color_ramp): ``props['elements']``
    ((position, (r, g, b, a)) pairs, ascending), ``interpolation``, ``color_mode``,
    ``hue_interpolation``.  Outputs 'Color' and 'Alpha'."""
    elements = node.props.get("elements") or ((0.0, (0, 0, 0, 1)), (1.0, (1, 1, 1, 1)))
    pos = [float(p) for p, _ in elements]
    cols = [tuple(c) for _, c in elements]
    c, a = col.color_ramp(ctx.value(node, "Fac", 0.5), pos, cols,
                          node.props.get("interpolation", "LINEAR"),
                          node.props.get("color_mode", "RGB"),
                          node.props.get("hue_interpolation", "NEAR"))
    return {"Color": (c, RGBA), "Alpha": (a, VALUE)}


def _mix_check(node):
    kind = node.props.get("data_type", "FLOAT")
    if kind not in ("FLOAT", "VECTOR", "RGBA"):
        return f"is not supported with data type {kind}"
    if kind == "RGBA" and node.props.get("blend_type", "MIX") not in col.BLEND:
        return f"is not supported with blend type {node.props.get('blend_type')}"
    return None


@_kind("ShaderNodeMix", check=_mix_check)
def _mix(ctx, node, wanted):
    """Mix (``svm_node_mix_float``, ``svm_node_mix_vector``, ``svm_node_mix_color``): FLOAT
    and VECTOR interpolate A -> B by Factor (per component with the NON_UNIFORM factor
    mode); RGBA blends by ``blend_type`` (colour.BLEND); ``clamp_factor`` clamps the factor
    to [0, 1], ``clamp_result`` (RGBA) the colour."""
    kind = node.props.get("data_type", "FLOAT")
    clamp = bool(node.props.get("clamp_factor", True))
    if kind == "VECTOR" and node.props.get("factor_mode", "UNIFORM") == "NON_UNIFORM":
        t = ctx.vector(node, "Factor_Vector", (0.5, 0.5, 0.5))
    else:
        t = ctx.value(node, "Factor_Float", 0.5)
    if clamp:
        t = np.clip(t, 0.0, 1.0)
    if kind == "FLOAT":
        a, b = ctx.value(node, "A_Float"), ctx.value(node, "B_Float")
        return {"Result_Float": (a * (1.0 - t) + b * t, VALUE)}
    if kind == "VECTOR":
        a, b = ctx.vector(node, "A_Vector"), ctx.vector(node, "B_Vector")
        t = t if t.ndim == 2 else t[:, None]
        return {"Result_Vector": (a * (1.0 - t) + b * t, VECTOR)}
    a = ctx.colour(node, "A_Color", (0.5, 0.5, 0.5, 1.0))
    b = ctx.colour(node, "B_Color", (0.5, 0.5, 0.5, 1.0))
    out = col.BLEND[node.props.get("blend_type", "MIX")](t[:, None], a, b)
    if node.props.get("clamp_result", False):
        out = np.clip(out, 0.0, 1.0)
    return {"Result_Color": (out, RGBA)}


@_kind("ShaderNodeMixRGB",
       check=lambda node: None if node.props.get("blend_type", "MIX") in col.BLEND
       else f"is not supported with blend type {node.props.get('blend_type')}")
def _mix_rgb(ctx, node, wanted):
    """The legacy MixRGB (``svm_node_mix``): blends Color1 and Color2 by ``blend_type`` with
    the factor clamped to [0, 1]; ``use_clamp`` clamps the result."""
    t = np.clip(ctx.value(node, "Fac", 0.5), 0.0, 1.0)[:, None]
    out = col.BLEND[node.props.get("blend_type", "MIX")](
        t, ctx.colour(node, "Color1", (0.5, 0.5, 0.5, 1.0)),
        ctx.colour(node, "Color2", (0.5, 0.5, 0.5, 1.0)))
    if node.props.get("use_clamp", False):
        out = np.clip(out, 0.0, 1.0)
    return {"Color": (out, RGBA)}


@_kind("ShaderNodeInvert")
def _invert(ctx, node, wanted):
    """Invert (``svm_node_invert``): Color + Fac (1 - 2 Color)."""
    c = ctx.colour(node, "Color", (0.0, 0.0, 0.0, 1.0))
    t = ctx.value(node, "Fac", 1.0)[:, None]
    return {"Color": ((1.0 - t) * c + t * (1.0 - c), RGBA)}


_TO_RGB = {"RGB": lambda c: c, "HSV": col.hsv_to_rgb, "HSL": col.hsl_to_rgb}
_FROM_RGB = {"RGB": lambda c: c, "HSV": col.rgb_to_hsv, "HSL": col.rgb_to_hsl}


@_kind("ShaderNodeSeparateColor")
def _separate_color(ctx, node, wanted):
    """Separate Color (``svm_separate_color``): RGB, HSV or HSL components (``mode``)."""
    c = _FROM_RGB[node.props.get("mode", "RGB")](ctx.colour(node, "Color", (0.8, 0.8, 0.8, 1)))
    return {k: (c[:, i], VALUE) for i, k in enumerate(("Red", "Green", "Blue"))}


@_kind("ShaderNodeCombineColor")
def _combine_color(ctx, node, wanted):
    """Combine Color (``svm_combine_color``): from RGB, HSV or HSL components (``mode``)."""
    c = np.stack([ctx.value(node, k) for k in ("Red", "Green", "Blue")], axis=1)
    return {"Color": (_TO_RGB[node.props.get("mode", "RGB")](c), RGBA)}


@_kind("ShaderNodeBlackbody")
def _blackbody(ctx, node, wanted):
    """Blackbody: the unit-luminance linear Rec.709 colour of a blackbody at Temperature
    (kelvin, clamped to 800..12000 K; mpp_render.blackbody.colour)."""
    from .. import blackbody
    return {"Color": (blackbody.colour(ctx.value(node, "Temperature", 1500.0)), RGBA)}


# -- textures -------------------------------------------------------------------------------

def _texture_reads(node, output):
    return set() if "Vector" in node.inputs else {"generated"}


def _module_check(module: str, function: str):
    """A check that the texture module (written beside this one) can be imported."""
    def check(node):
        try:
            mod = importlib.import_module(f"{__package__}.{module}")
        except ImportError as e:
            return f"needs mpp_render.textures.{module}, which cannot be imported ({e})"
        if not hasattr(mod, function):
            return f"needs mpp_render.textures.{module}.{function}, which is missing"
        return None
    return check


def _texture(module: str):
    return importlib.import_module(f"{__package__}.{module}")


@_kind("ShaderNodeTexNoise", reads=_texture_reads,
       check=_module_check("noise", "noise_texture"))
def _noise(ctx, node, wanted):
    """Noise Texture (noise.noise_texture): 'Fac' and 'Color'."""
    p = node.props
    fac, colour_out = _texture("noise").noise_texture(
        ctx.texture_vector(node), w=ctx.param(node, "W"),
        dimensions=p.get("noise_dimensions", "3D"), scale=ctx.param(node, "Scale", 5.0),
        detail=ctx.param(node, "Detail", 2.0), roughness=ctx.param(node, "Roughness", 0.5),
        lacunarity=ctx.param(node, "Lacunarity", 2.0), offset=ctx.param(node, "Offset"),
        gain=ctx.param(node, "Gain", 1.0), distortion=ctx.param(node, "Distortion"),
        noise_type=p.get("noise_type", "FBM"), normalize=bool(p.get("normalize", True)),
        color="Color" in wanted)
    out = {"Fac": (np.asarray(fac, np.float64), VALUE)}
    if colour_out is not None:
        out["Color"] = (np.asarray(colour_out, np.float64), RGBA)
    return out


_VORONOI_TYPES = {"Distance": VALUE, "Color": RGBA, "Position": VECTOR, "W": VALUE,
                  "Radius": VALUE}


@_kind("ShaderNodeTexVoronoi", reads=_texture_reads,
       check=_module_check("voronoi", "voronoi_texture"))
def _voronoi(ctx, node, wanted):
    """Voronoi Texture (voronoi.voronoi_texture): 'Distance', 'Color', 'Position', 'W',
    'Radius' (those the feature gives)."""
    p = node.props
    outs = _texture("voronoi").voronoi_texture(
        ctx.texture_vector(node), w=ctx.param(node, "W"),
        dimensions=p.get("voronoi_dimensions", "3D"), feature=p.get("feature", "F1"),
        distance=p.get("distance", "EUCLIDEAN"), scale=ctx.param(node, "Scale", 5.0),
        detail=ctx.param(node, "Detail"), roughness=ctx.param(node, "Roughness", 0.5),
        lacunarity=ctx.param(node, "Lacunarity", 2.0),
        smoothness=ctx.param(node, "Smoothness", 1.0),
        exponent=ctx.param(node, "Exponent", 0.5), randomness=ctx.param(node, "Randomness", 1.0),
        normalize=bool(p.get("normalize", False)), outputs=set(wanted))
    return {k: (np.asarray(v, np.float64), _VORONOI_TYPES.get(k, VALUE)) for k, v in outs.items()}


@_kind("ShaderNodeTexGradient", reads=_texture_reads,
       check=_module_check("gradient", "gradient_texture"))
def _gradient(ctx, node, wanted):
    """Gradient Texture (gradient.gradient_texture, clamped to [0, 1] as Cycles): 'Fac' and
    'Color' (grey)."""
    fac = np.asarray(_texture("gradient").gradient_texture(
        ctx.texture_vector(node), gradient_type=node.props.get("gradient_type", "LINEAR")),
        np.float64)
    return {"Fac": (fac, VALUE), "Color": (np.repeat(fac[:, None], 3, axis=1), RGBA)}


@_kind("ShaderNodeTexWave", reads=_texture_reads, check=_module_check("wave", "wave_texture"))
def _wave(ctx, node, wanted):
    """Wave Texture (wave.wave_texture): 'Fac' and 'Color'."""
    p = node.props
    fac, colour_out = _texture("wave").wave_texture(
        ctx.texture_vector(node), wave_type=p.get("wave_type", "BANDS"),
        bands_direction=p.get("bands_direction", "X"),
        rings_direction=p.get("rings_direction", "X"), wave_profile=p.get("wave_profile", "SIN"),
        scale=ctx.param(node, "Scale", 5.0), distortion=ctx.param(node, "Distortion"),
        detail=ctx.param(node, "Detail", 2.0), detail_scale=ctx.param(node, "Detail Scale", 1.0),
        detail_roughness=ctx.param(node, "Detail Roughness", 0.5),
        phase_offset=ctx.param(node, "Phase Offset"))
    fac = np.asarray(fac, np.float64)
    if colour_out is None:
        colour_out = np.repeat(fac[:, None], 3, axis=1)
    return {"Fac": (fac, VALUE), "Color": (np.asarray(colour_out, np.float64), RGBA)}
