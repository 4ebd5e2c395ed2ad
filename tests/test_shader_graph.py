"""Shader node trees evaluated on points (mpp_render.textures.graph): each node's semantics on
small arrays, against hand-written formulas, Python's colorsys and Blender's documented edge
cases (the safe_* functions).  No bpy: the glue that builds graphs from Blender trees (and
flattens groups) is tested in tests/blender/test_shader_graph_bpy.py."""
import colorsys
import importlib
import importlib.util

import numpy as np
import pytest

from mpp_render.textures import colour as col
from mpp_render.textures import graph as g
from mpp_render.textures import mathops

# Blender 5.0's enum items (ShaderNodeMath / ShaderNodeVectorMath operation, Mix blend_type)
BLENDER_MATH = ['ADD', 'SUBTRACT', 'MULTIPLY', 'DIVIDE', 'MULTIPLY_ADD', 'POWER', 'LOGARITHM',
                'SQRT', 'INVERSE_SQRT', 'ABSOLUTE', 'EXPONENT', 'MINIMUM', 'MAXIMUM', 'LESS_THAN',
                'GREATER_THAN', 'SIGN', 'COMPARE', 'SMOOTH_MIN', 'SMOOTH_MAX', 'ROUND', 'FLOOR',
                'CEIL', 'TRUNC', 'FRACT', 'MODULO', 'FLOORED_MODULO', 'WRAP', 'SNAP', 'PINGPONG',
                'SINE', 'COSINE', 'TANGENT', 'ARCSINE', 'ARCCOSINE', 'ARCTANGENT', 'ARCTAN2',
                'SINH', 'COSH', 'TANH', 'RADIANS', 'DEGREES']
BLENDER_VECTOR_MATH = ['ADD', 'SUBTRACT', 'MULTIPLY', 'DIVIDE', 'MULTIPLY_ADD', 'CROSS_PRODUCT',
                       'PROJECT', 'REFLECT', 'REFRACT', 'FACEFORWARD', 'DOT_PRODUCT', 'DISTANCE',
                       'LENGTH', 'SCALE', 'NORMALIZE', 'ABSOLUTE', 'POWER', 'SIGN', 'MINIMUM',
                       'MAXIMUM', 'FLOOR', 'CEIL', 'FRACTION', 'MODULO', 'WRAP', 'SNAP', 'SINE',
                       'COSINE', 'TANGENT']
BLENDER_BLEND = ['MIX', 'DARKEN', 'MULTIPLY', 'BURN', 'LIGHTEN', 'SCREEN', 'DODGE', 'ADD',
                 'OVERLAY', 'SOFT_LIGHT', 'LINEAR_LIGHT', 'DIFFERENCE', 'EXCLUSION', 'SUBTRACT',
                 'DIVIDE', 'HUE', 'SATURATION', 'COLOR', 'VALUE']


def one(kind, output, props=None, n=None, **inputs):
    """Evaluate output ``output`` of a single node with constant ``inputs`` at n points."""
    node = g.Node(kind, dict(props or {}), dict(inputs), "n")
    graph = g.Graph({"n": node})
    pts = g.Points(np.zeros((n or 1, 3)))
    return g.evaluate(graph, g.Link("n", output), pts)


def on_points(kind, output, props, values: dict, extra=None):
    """Node ``kind`` whose inputs are the per-point values ``values`` (identifier -> (N,) or
    (N,3) array), fed through Attribute nodes."""
    nodes, inputs, attrs = {}, dict(extra or {}), {}
    for i, (ident, v) in enumerate(values.items()):
        v = np.asarray(v, np.float64)
        name = f"a{i}"
        attrs[name] = v
        nodes[name] = g.Node("ShaderNodeAttribute", {"attribute_name": name}, {}, name)
        inputs[ident] = g.Link(name, "Fac" if v.ndim == 1 else "Vector")
    nodes["n"] = g.Node(kind, dict(props), inputs, "n")
    n = len(next(iter(values.values())))
    return g.evaluate(g.Graph(nodes), g.Link("n", output), g.Points(np.zeros((n, 3)),
                                                                     attributes=attrs))


# -- Math -------------------------------------------------------------------------------------

def test_every_blender_math_operation_is_in_the_table():
    assert sorted(mathops.MATH) == sorted(BLENDER_MATH)
    assert sorted(mathops.VECTOR_MATH) == sorted(BLENDER_VECTOR_MATH)
    assert sorted(col.BLEND) == sorted(BLENDER_BLEND)


A = np.array([-2.5, -1.0, -0.5, 0.0, 0.3, 1.0, 2.0, 7.25])
B = np.array([0.0, 2.0, 0.5, -1.5, 0.0, 3.0, -0.7, 2.0])
C = np.array([0.1, 0.0, 1.0, 0.2, 0.5, -1.0, 0.3, 0.0])


def math(op, a=A, b=B, c=C, clamp=False):
    return on_points("ShaderNodeMath", "Value", {"operation": op, "use_clamp": clamp},
                     {"Value": a, "Value_001": b, "Value_002": c})


def test_math_safe_functions_follow_blender():
    # divide, modulo, snap by 0 give 0
    assert math("DIVIDE")[[0, 4]] == pytest.approx([0.0, 0.0])
    assert math("DIVIDE")[1] == pytest.approx(-0.5)
    assert math("MODULO")[[0, 4]] == pytest.approx([0.0, 0.0])
    assert math("FLOORED_MODULO")[[0, 4]] == pytest.approx([0.0, 0.0])
    assert math("SNAP")[[0, 4]] == pytest.approx([0.0, 0.0])
    # truncated (C fmod) and floored modulo
    assert math("MODULO", a=np.array([-7.0]), b=np.array([3.0]))[0] == pytest.approx(-1.0)
    assert math("FLOORED_MODULO", a=np.array([-7.0]), b=np.array([3.0]))[0] == pytest.approx(2.0)
    # power: a negative base with a non-integer exponent is 0; with an integer one it is pow
    p = math("POWER", a=np.array([-2.0, -2.0, 4.0, -8.0]), b=np.array([0.5, 3.0, 0.5, 2.0]))
    assert p == pytest.approx([0.0, -8.0, 2.0, 64.0])
    # log: 0 for a <= 0 or base <= 0; log base 1 is a division by 0
    lg = math("LOGARITHM", a=np.array([8.0, -1.0, 0.0, 8.0, 5.0]),
              b=np.array([2.0, 2.0, 2.0, -2.0, 1.0]))
    assert lg == pytest.approx([3.0, 0.0, 0.0, 0.0, 0.0])
    assert math("SQRT", a=np.array([-4.0, 9.0]))[[0, 1]] == pytest.approx([0.0, 3.0])
    assert math("INVERSE_SQRT", a=np.array([-4.0, 0.0, 4.0])) == pytest.approx([0.0, 0.0, 0.5])
    assert math("ARCSINE", a=np.array([2.0, -3.0])) == pytest.approx([np.pi / 2, -np.pi / 2])
    assert math("ARCCOSINE", a=np.array([2.0, -3.0])) == pytest.approx([0.0, np.pi])


def test_math_operations_against_formulas():
    expect = {
        "ADD": A + B, "SUBTRACT": A - B, "MULTIPLY": A * B, "MULTIPLY_ADD": A * B + C,
        "ABSOLUTE": np.abs(A), "EXPONENT": np.exp(A), "MINIMUM": np.minimum(A, B),
        "MAXIMUM": np.maximum(A, B), "LESS_THAN": (A < B) * 1.0, "GREATER_THAN": (A > B) * 1.0,
        "SIGN": np.sign(A), "ROUND": np.floor(A + 0.5), "FLOOR": np.floor(A),
        "CEIL": np.ceil(A), "TRUNC": np.trunc(A), "FRACT": A - np.floor(A),
        "SINE": np.sin(A), "COSINE": np.cos(A), "TANGENT": np.tan(A), "ARCTANGENT": np.arctan(A),
        "ARCTAN2": np.arctan2(A, B), "SINH": np.sinh(A), "COSH": np.cosh(A),
        "TANH": np.tanh(A), "RADIANS": np.radians(A), "DEGREES": np.degrees(A),
    }
    for op, want in expect.items():
        np.testing.assert_allclose(math(op), want, rtol=1e-12, atol=1e-12, err_msg=op)
    # wrap(a, max, min), pingpong, smooth min/max, compare
    w = math("WRAP", a=np.array([5.5, -0.5, 3.0]), b=np.array([2.0, 2.0, 1.0]),
             c=np.array([0.0, 0.0, 1.0]))
    assert w == pytest.approx([1.5, 1.5, 1.0])           # a zero range gives min
    pp = math("PINGPONG", a=np.array([0.25, 1.25, 2.5, 3.0]), b=np.array([1.0, 1.0, 1.0, 0.0]))
    assert pp == pytest.approx([0.25, 0.75, 0.5, 0.0])
    sm = math("SMOOTH_MIN", a=np.array([1.0, 1.0, 1.0]), b=np.array([1.2, 5.0, 1.2]),
              c=np.array([1.0, 1.0, 0.0]))
    assert sm == pytest.approx([1.0 - 0.8 ** 3 / 6.0, 1.0, 1.0])
    sx = math("SMOOTH_MAX", a=np.array([1.0]), b=np.array([1.2]), c=np.array([1.0]))
    assert sx == pytest.approx([1.2 + 0.8 ** 3 / 6.0])
    cmp_ = math("COMPARE", a=np.array([1.0, 1.0, 1.0]), b=np.array([1.05, 1.2, 1.0 + 1e-8]),
                c=np.array([0.1, 0.1, 0.0]))
    assert cmp_ == pytest.approx([1.0, 0.0, 1.0])         # FLT_EPSILON is the least tolerance
    assert math("ADD", clamp=True) == pytest.approx(np.clip(A + B, 0, 1))


# -- Vector Math --------------------------------------------------------------------------------

VA = np.array([[1.0, 2.0, -3.0], [0.0, 0.0, 0.0], [0.5, -1.5, 2.0]])
VB = np.array([[0.0, 0.0, 2.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
VC = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])


def vmath(op, output="Vector", a=VA, b=VB, c=VC, s=np.array([2.0, 0.5, -1.0])):
    return on_points("ShaderNodeVectorMath", output, {"operation": op},
                     {"Vector": a, "Vector_001": b, "Vector_002": c, "Scale": s})


def test_vector_math_operations():
    np.testing.assert_allclose(vmath("DIVIDE"), [[0, 0, -1.5], [0, 0, 0], [0, 0, 0]])
    np.testing.assert_allclose(vmath("CROSS_PRODUCT"), np.cross(VA, VB))
    np.testing.assert_allclose(vmath("PROJECT")[0], [0, 0, -3.0])
    np.testing.assert_allclose(vmath("PROJECT")[2], [0, 0, 0])        # onto a zero vector
    np.testing.assert_allclose(vmath("REFLECT")[0], [1.0, 2.0, 3.0])  # b normalised
    np.testing.assert_allclose(vmath("NORMALIZE")[1], [0, 0, 0])
    np.testing.assert_allclose(vmath("NORMALIZE")[0], VA[0] / np.linalg.norm(VA[0]))
    np.testing.assert_allclose(vmath("SCALE"), VA * [[2.0], [0.5], [-1.0]])
    np.testing.assert_allclose(vmath("DOT_PRODUCT", "Value"), (VA * VB).sum(1))
    np.testing.assert_allclose(vmath("DISTANCE", "Value"), np.linalg.norm(VA - VB, axis=1))
    np.testing.assert_allclose(vmath("LENGTH", "Value"), np.linalg.norm(VA, axis=1))
    np.testing.assert_allclose(vmath("LENGTH", "Vector"), 0.0)       # the other output is 0
    np.testing.assert_allclose(vmath("MULTIPLY_ADD"), VA * VB + VC)
    np.testing.assert_allclose(vmath("MODULO"), [[0, 0, -1.0], [0, 0, 0], [0, 0, 0]])
    np.testing.assert_allclose(vmath("POWER", a=np.array([[-2.0, 4.0, 2.0]]),
                                     b=np.array([[0.5, 0.5, -1.0]]), c=VC[:1],
                                     s=np.array([1.0])), [[0.0, 2.0, 0.5]])
    np.testing.assert_allclose(vmath("SIGN"), np.sign(VA))
    np.testing.assert_allclose(vmath("FACEFORWARD"), [[-1, -2, 3], [0, 0, 0], [-0.5, 1.5, -2]])
    np.testing.assert_allclose(vmath("WRAP", a=np.array([[5.5, -0.5, 3.0]]),
                                     b=np.array([[2.0, 2.0, 1.0]]), c=np.array([[0.0, 0.0, 1.0]]),
                                     s=np.array([1.0])), [[1.5, 1.5, 1.0]])
    np.testing.assert_allclose(vmath("SNAP", a=np.array([[2.7, -2.7, 1.0]]),
                                     b=np.array([[1.0, 1.0, 0.0]]), c=VC[:1],
                                     s=np.array([1.0])), [[2.0, -3.0, 0.0]])


def test_refract_matches_snell_and_gives_zero_at_total_internal_reflection():
    i = np.array([[np.sin(0.5), 0.0, -np.cos(0.5)], [np.sin(1.2), 0.0, -np.cos(1.2)]])
    n = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]])   # b is normalised first
    out = vmath("REFRACT", a=i, b=n, c=VC[:2], s=np.array([1 / 1.5, 1.5]))
    assert out[0, 0] == pytest.approx(np.sin(0.5) / 1.5)      # Snell: sin t = eta sin i
    assert np.linalg.norm(out[0]) == pytest.approx(1.0)
    np.testing.assert_allclose(out[1], 0.0)                   # 1.5 sin(1.2) > 1


# -- Map Range, Clamp ---------------------------------------------------------------------------

X = np.array([-1.0, 0.0, 0.25, 0.5, 1.0, 2.0])


def map_range(kind, clamp=False, x=X, lo=0.0, hi=1.0, to_lo=10.0, to_hi=20.0, steps=4.0):
    return on_points("ShaderNodeMapRange", "Result",
                     {"interpolation_type": kind, "clamp": clamp, "data_type": "FLOAT"},
                     {"Value": x}, {"From Min": lo, "From Max": hi, "To Min": to_lo,
                                    "To Max": to_hi, "Steps": steps})


def test_map_range_modes():
    np.testing.assert_allclose(map_range("LINEAR"), 10 + 10 * X)
    np.testing.assert_allclose(map_range("LINEAR", clamp=True), 10 + 10 * np.clip(X, 0, 1))
    np.testing.assert_allclose(map_range("LINEAR", clamp=True, to_lo=20.0, to_hi=10.0),
                               20 - 10 * np.clip(X, 0, 1))      # a reversed target range
    np.testing.assert_allclose(map_range("STEPPED"), 10 + 10 * np.floor(X * 5) / 4)
    t = np.clip(X, 0, 1)
    np.testing.assert_allclose(map_range("SMOOTHSTEP"), 10 + 10 * t * t * (3 - 2 * t))
    np.testing.assert_allclose(map_range("SMOOTHERSTEP"),
                               10 + 10 * t ** 3 * (t * (6 * t - 15) + 10))
    # a reversed source range: Cycles' 1 - smoothstep(max, min, x)
    rt = np.clip(1 - X, 0, 1)
    np.testing.assert_allclose(map_range("SMOOTHSTEP", lo=1.0, hi=0.0),
                               10 + 10 * rt * rt * (3 - 2 * rt))
    np.testing.assert_allclose(map_range("LINEAR", lo=0.5, hi=0.5), 0.0)   # Cycles: 0
    np.testing.assert_allclose(map_range("STEPPED", steps=0.0), 10.0)


def test_vector_map_range():
    v = np.array([[0.5, 2.0, -1.0]])
    out = on_points("ShaderNodeMapRange", "Vector",
                    {"interpolation_type": "LINEAR", "clamp": True, "data_type": "FLOAT_VECTOR"},
                    {"Vector": v}, {"From_Min_FLOAT3": (0, 0, 0), "From_Max_FLOAT3": (1, 1, 0),
                                    "To_Min_FLOAT3": (0, 0, 5), "To_Max_FLOAT3": (2, 2, 6)})
    np.testing.assert_allclose(out, [[1.0, 2.0, 5.0]])   # z: a zero range gives factor 0


def test_clamp_minmax_and_range():
    v = np.array([-1.0, 0.5, 3.0])
    mm = on_points("ShaderNodeClamp", "Result", {"clamp_type": "MINMAX"}, {"Value": v},
                   {"Min": 2.0, "Max": 1.0})
    assert mm == pytest.approx([1.0, 1.0, 1.0])       # min(max(v, 2), 1)
    rg = on_points("ShaderNodeClamp", "Result", {"clamp_type": "RANGE"}, {"Value": v},
                   {"Min": 2.0, "Max": 1.0})
    assert rg == pytest.approx([1.0, 1.0, 2.0])


# -- Color Ramp ---------------------------------------------------------------------------------

RAMP = ((0.2, (1.0, 0.0, 0.0, 1.0)), (0.5, (0.0, 1.0, 0.0, 0.5)), (0.9, (0.0, 0.0, 1.0, 0.0)))


def ramp(x, interpolation, elements=RAMP, mode="RGB", hue="NEAR"):
    props = {"elements": elements, "interpolation": interpolation, "color_mode": mode,
             "hue_interpolation": hue}
    x = np.asarray(x, np.float64)
    c = on_points("ShaderNodeValToRGB", "Color", props, {"Fac": x})
    a = on_points("ShaderNodeValToRGB", "Alpha", props, {"Fac": x})
    return c, a


def test_color_ramp_linear_constant_ease():
    c, a = ramp([0.0, 0.2, 0.35, 0.5, 0.7, 0.9, 1.0], "LINEAR")
    np.testing.assert_allclose(c, [[1, 0, 0], [1, 0, 0], [0.5, 0.5, 0], [0, 1, 0],
                                   [0, 0.5, 0.5], [0, 0, 1], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(a, [1, 1, 0.75, 0.5, 0.25, 0, 0], atol=1e-12)
    c, _ = ramp([0.1, 0.3, 0.49, 0.5, 0.6, 0.95], "CONSTANT")
    np.testing.assert_allclose(c, [[1, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0],
                                   [0, 0, 1]])
    c, _ = ramp([0.275], "EASE")                    # a quarter of the way: smoothstep 0.15625
    np.testing.assert_allclose(c, [[1 - 0.15625, 0.15625, 0]])


def test_color_ramp_splines():
    # B-spline at an element's position: (1/6, 2/3, 1/6) of it and its neighbours
    c, a = ramp([0.5], "B_SPLINE")
    np.testing.assert_allclose(c, [[0.16666666, 0.66666666, 0.16666666]], atol=1e-7)
    assert a[0] == pytest.approx(0.16666666 + 0.66666666 * 0.5, abs=1e-7)
    # cardinal interpolates the elements themselves
    c, _ = ramp([0.2, 0.5, 0.9], "CARDINAL")
    np.testing.assert_allclose(c, [[1, 0, 0], [0, 1, 0], [0, 0, 1]], atol=1e-7)
    # between elements the cardinal weights (fc = 0.71) at t = 1/2 of the way back
    c, _ = ramp([0.35], "CARDINAL")
    t = 0.5
    w1 = (2 - 0.71) * t ** 3 + (0.71 - 3) * t ** 2 + 1   # weight of the element above
    w2 = (0.71 - 2) * t ** 3 + (3 - 2 * 0.71) * t ** 2 + 0.71 * t
    w0 = -0.71 * t ** 3 + 2 * 0.71 * t ** 2 - 0.71 * t    # the one after it
    np.testing.assert_allclose(c[0], np.clip([w2 + 0.71 * t ** 3 - 0.71 * t ** 2, w1, w0], 0, 1),
                               atol=1e-7)


def test_color_ramp_hsv_mode_goes_round_the_hue_circle():
    red_blue = ((0.0, (1.0, 0.0, 0.0, 1.0)), (1.0, (0.0, 0.0, 1.0, 1.0)))
    near, _ = ramp([0.5], "LINEAR", red_blue, mode="HSV", hue="NEAR")
    far, _ = ramp([0.5], "LINEAR", red_blue, mode="HSV", hue="FAR")
    np.testing.assert_allclose(near[0], [1.0, 0.0, 1.0], atol=1e-9)   # via magenta
    np.testing.assert_allclose(far[0], [0.0, 1.0, 0.0], atol=1e-9)    # via green
    hsl, _ = ramp([0.5], "LINEAR", red_blue, mode="HSL", hue="NEAR")
    np.testing.assert_allclose(hsl[0], [1.0, 0.0, 1.0], atol=1e-9)


# -- colours ------------------------------------------------------------------------------------

def test_hsv_hsl_against_colorsys_and_round_trips():
    rgb = np.random.default_rng(3).random((200, 3))
    hsv = col.rgb_to_hsv(rgb)
    hls = np.array([colorsys.rgb_to_hls(*c) for c in rgb])
    np.testing.assert_allclose(hsv, [colorsys.rgb_to_hsv(*c) for c in rgb], atol=1e-12)
    np.testing.assert_allclose(col.rgb_to_hsl(rgb), hls[:, [0, 2, 1]], atol=1e-12)
    np.testing.assert_allclose(col.hsv_to_rgb(hsv), rgb, atol=1e-12)
    np.testing.assert_allclose(col.hsl_to_rgb(col.rgb_to_hsl(rgb)), rgb, atol=1e-12)
    grey = col.rgb_to_hsv(np.array([[0.3, 0.3, 0.3], [0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(grey, [[0, 0, 0.3], [0, 0, 0]])
    sep = on_points("ShaderNodeSeparateColor", "Red", {"mode": "HSV"},
                    {"Color": np.array([[0.0, 1.0, 0.0]])})
    assert sep[0] == pytest.approx(1 / 3)
    comb = on_points("ShaderNodeCombineColor", "Color", {"mode": "HSL"},
                     {"Red": np.array([2 / 3]), "Green": np.array([1.0]),
                      "Blue": np.array([0.5])})
    np.testing.assert_allclose(comb, [[0.0, 0.0, 1.0]], atol=1e-12)


C1 = np.array([[0.2, 0.6, 0.9], [0.8, 0.3, 0.0], [0.5, 0.5, 0.5]])
C2 = np.array([[0.5, 0.1, 0.0], [0.4, 0.9, 0.6], [0.0, 0.2, 1.0]])


def mix(blend, t, c1=C1, c2=C2, clamp_factor=True, clamp_result=False):
    return on_points("ShaderNodeMix", "Result_Color",
                     {"data_type": "RGBA", "blend_type": blend, "clamp_factor": clamp_factor,
                      "clamp_result": clamp_result},
                     {"Factor_Float": np.full(len(c1), t), "A_Color": c1, "B_Color": c2})


def test_mix_blend_modes():
    t = 0.3
    lerp = lambda b: C1 + t * (b - C1)  # noqa: E731
    expect = {
        "MIX": lerp(C2), "ADD": lerp(C1 + C2), "MULTIPLY": lerp(C1 * C2),
        "SUBTRACT": lerp(C1 - C2), "DIFFERENCE": lerp(np.abs(C1 - C2)),
        "DARKEN": lerp(np.minimum(C1, C2)), "LIGHTEN": lerp(np.maximum(C1, C2)),
        "EXCLUSION": np.maximum(lerp(C1 + C2 - 2 * C1 * C2), 0),
        "SCREEN": 1 - (1 - t + t * (1 - C2)) * (1 - C1),
        "LINEAR_LIGHT": C1 + t * (2 * C2 - 1),
        "SOFT_LIGHT": (1 - t) * C1 + t * ((1 - C1) * C2 * C1 + C1 * (1 - (1 - C2) * (1 - C1))),
        "OVERLAY": np.where(C1 < 0.5, C1 * (1 - t + 2 * t * C2),
                            1 - (1 - t + 2 * t * (1 - C2)) * (1 - C1)),
    }
    for blend, want in expect.items():
        np.testing.assert_allclose(mix(blend, t), want, atol=1e-12, err_msg=blend)
    div = mix("DIVIDE", t)
    np.testing.assert_allclose(div[0, 2], C1[0, 2])                 # by 0: unchanged
    assert div[0, 0] == pytest.approx(0.7 * 0.2 + 0.3 * 0.2 / 0.5)
    dodge = mix("DODGE", 1.0)
    assert dodge[0, 0] == pytest.approx(0.4) and dodge[1, 1] == 1.0  # 0.3 / 0.1 clamps at 1
    burn = mix("BURN", 1.0)
    assert burn[0, 0] == pytest.approx(0.0) and burn[1, 1] == pytest.approx(1 - 0.7 / 0.9)
    # HSV modes at t = 1: the hue / saturation / value of B on A
    hue = col.rgb_to_hsv(mix("HUE", 1.0))
    np.testing.assert_allclose(hue[:2, 0], col.rgb_to_hsv(C2)[:2, 0], atol=1e-12)
    np.testing.assert_allclose(mix("HUE", 1.0)[2], C1[2])              # grey A keeps
    val = col.rgb_to_hsv(mix("VALUE", 1.0))
    np.testing.assert_allclose(val[:, 2], C2.max(axis=1), atol=1e-12)
    sat = col.rgb_to_hsv(mix("SATURATION", 1.0))
    np.testing.assert_allclose(sat[:2, 1], col.rgb_to_hsv(C2)[:2, 1], atol=1e-12)
    colour = col.rgb_to_hsv(mix("COLOR", 1.0))
    np.testing.assert_allclose(colour[:2, :2], col.rgb_to_hsv(C2)[:2, :2], atol=1e-12)
    # factor and result clamping
    np.testing.assert_allclose(mix("MIX", 1.5), C2)
    np.testing.assert_allclose(mix("MIX", 1.5, clamp_factor=False), C1 + 1.5 * (C2 - C1))
    np.testing.assert_allclose(mix("ADD", 1.0, clamp_result=True), np.clip(C1 + C2, 0, 1))
    legacy = on_points("ShaderNodeMixRGB", "Color", {"blend_type": "MULTIPLY", "use_clamp": False},
                       {"Fac": np.full(3, 2.0), "Color1": C1, "Color2": C2})
    np.testing.assert_allclose(legacy, C1 * C2)                      # factor clamped to 1


def test_mix_float_and_vector():
    f = on_points("ShaderNodeMix", "Result_Float", {"data_type": "FLOAT", "clamp_factor": False},
                  {"Factor_Float": np.array([0.25, 2.0]), "A_Float": np.array([1.0, 1.0]),
                   "B_Float": np.array([3.0, 3.0])})
    assert f == pytest.approx([1.5, 5.0])
    v = on_points("ShaderNodeMix", "Result_Vector",
                  {"data_type": "VECTOR", "factor_mode": "NON_UNIFORM", "clamp_factor": True},
                  {"Factor_Vector": np.array([[0.0, 0.5, 2.0]]), "A_Vector": np.zeros((1, 3)),
                   "B_Vector": np.array([[2.0, 2.0, 2.0]])})
    np.testing.assert_allclose(v, [[0.0, 1.0, 2.0]])
    u = on_points("ShaderNodeMix", "Result_Vector", {"data_type": "VECTOR"},
                  {"Factor_Float": np.array([0.5]), "A_Vector": np.zeros((1, 3)),
                   "B_Vector": np.array([[2.0, 4.0, 6.0]])})
    np.testing.assert_allclose(u, [[1.0, 2.0, 3.0]])


def test_invert_and_separate_combine():
    inv = on_points("ShaderNodeInvert", "Color", {}, {"Color": C1, "Fac": np.array([1, 0.5, 0])})
    np.testing.assert_allclose(inv, [1 - C1[0], [0.5] * 3, C1[2]])
    xyz = on_points("ShaderNodeSeparateXYZ", "Y", {}, {"Vector": VA})
    np.testing.assert_allclose(xyz, VA[:, 1])
    comb = on_points("ShaderNodeCombineXYZ", "Vector", {},
                     {"X": VA[:, 0], "Z": VA[:, 2]}, {"Y": 7.0})
    np.testing.assert_allclose(comb, np.c_[VA[:, 0], [7.0] * 3, VA[:, 2]])


# -- conversions, coordinates, grids ------------------------------------------------------------

def test_implicit_conversions():
    rgb = np.array([[1.0, 0.0, 0.0], [0.2, 0.4, 0.8]])
    lum = on_points("ShaderNodeMath", "Value", {"operation": "ADD"},
                    {"Value": np.zeros(2)}, {"Value_001": 0.0})
    assert lum == pytest.approx([0, 0])
    # an RGB node into a Math node: Rec.709 luminance; a vector: the mean of its components
    graph = g.Graph({
        "rgb": g.Node("ShaderNodeRGB", {"color": (0.2, 0.4, 0.8, 1.0)}),
        "m": g.Node("ShaderNodeMath", {"operation": "ADD"},
                    {"Value": g.Link("rgb", "Color"), "Value_001": 0.0}),
        "xyz": g.Node("ShaderNodeCombineXYZ", {}, {"X": 0.2, "Y": 0.4, "Z": 0.8}),
        "m2": g.Node("ShaderNodeMath", {"operation": "ADD"},
                     {"Value": g.Link("xyz", "Vector"), "Value_001": 0.0}),
        "v": g.Node("ShaderNodeValue", {"value": 0.25}),
        "sep": g.Node("ShaderNodeSeparateColor", {"mode": "RGB"}, {"Color": g.Link("v", "Value")}),
        "conv": g.Node(g.CONVERT, {"to": "VALUE"}, {"Value": g.Link("rgb", "Color")}),
    })
    pts = g.Points(np.zeros((1, 3)))
    assert g.evaluate(graph, g.Link("m", "Value"), pts)[0] == pytest.approx(
        0.2 * 0.2126 + 0.4 * 0.7152 + 0.8 * 0.0722)
    assert g.evaluate(graph, g.Link("m2", "Value"), pts)[0] == pytest.approx(1.4 / 3)
    assert g.evaluate(graph, g.Link("sep", "Blue"), pts)[0] == pytest.approx(0.25)
    assert g.evaluate(graph, g.Link("conv", "Value"), pts, "RGBA")[0] == pytest.approx(
        [0.2 * 0.2126 + 0.4 * 0.7152 + 0.8 * 0.0722] * 3)
    assert g.reads(graph, g.Link("m", "Value")) == set()


def test_coordinates_mapping_and_what_a_graph_reads():
    pos = np.array([[1.0, 2.0, 3.0], [-1.0, 0.5, 0.0]])
    gen = pos * 0.1 + 0.5
    obj = pos - 1.0
    graph = g.Graph({
        "tc": g.Node("ShaderNodeTexCoord"),
        "geo": g.Node("ShaderNodeNewGeometry"),
        "map": g.Node("ShaderNodeMapping", {"vector_type": "POINT"},
                      {"Vector": g.Link("tc", "Object"), "Location": (1.0, 0.0, 0.0),
                       "Rotation": (0.0, 0.0, np.pi / 2), "Scale": (2.0, 2.0, 2.0)}),
        "tex": g.Node("ShaderNodeMapping", {"vector_type": "TEXTURE"},
                      {"Vector": g.Link("map", "Vector"), "Location": (1.0, 0.0, 0.0),
                       "Rotation": (0.0, 0.0, np.pi / 2), "Scale": (2.0, 2.0, 2.0)}),
        "nrm": g.Node("ShaderNodeMapping", {"vector_type": "NORMAL"},
                      {"Vector": (1.0, 0.0, 0.0), "Scale": (2.0, 1.0, 1.0)}),
        "tco": g.Node("ShaderNodeTexCoord", {"object_matrix": tuple(np.eye(4).ravel() * 2)}),
    })
    pts = g.Points(pos, generated=gen, object=obj)
    ev = lambda n, s: g.evaluate(graph, g.Link(n, s), pts)  # noqa: E731
    np.testing.assert_allclose(ev("tc", "Generated"), gen)
    np.testing.assert_allclose(ev("tc", "Object"), obj)
    np.testing.assert_allclose(ev("geo", "Position"), pos)
    # POINT: rotate 2 x obj by 90 degrees about z, then move by +x
    want = np.c_[-2 * obj[:, 1] + 1, 2 * obj[:, 0], 2 * obj[:, 2]]
    np.testing.assert_allclose(ev("map", "Vector"), want, atol=1e-12)
    np.testing.assert_allclose(ev("tex", "Vector"), obj, atol=1e-12)   # TEXTURE undoes POINT
    np.testing.assert_allclose(ev("nrm", "Vector"), [[1, 0, 0]] * 2, atol=1e-12)
    np.testing.assert_allclose(ev("tco", "Object")[:, :3], 2 * pos)
    assert g.reads(graph, g.Link("tex", "Vector")) == {"object"}
    assert g.reads(graph, g.Link("tco", "Object")) == {"position"}
    assert g.reads(graph, g.Link("tc", "Generated")) == {"generated"}


def test_attribute_and_volume_info_read_grids_and_zero_where_missing():
    n = 3
    attrs = {"density": np.array([0.0, 1.0, 2.0]),
             "color": np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 1.0], [1.0, 1.0, 1.0]])}
    graph = g.Graph({"a": g.Node("ShaderNodeAttribute", {"attribute_name": "density"}),
                     "c": g.Node("ShaderNodeAttribute", {"attribute_name": "color"}),
                     "m": g.Node("ShaderNodeAttribute", {"attribute_name": "missing"}),
                     "vi": g.Node("ShaderNodeVolumeInfo")})
    pts = g.Points(np.zeros((n, 3)), attributes=attrs)
    ev = lambda node, s: g.evaluate(graph, g.Link(node, s), pts)  # noqa: E731
    np.testing.assert_allclose(ev("a", "Fac"), attrs["density"])
    np.testing.assert_allclose(ev("a", "Color"), np.repeat(attrs["density"][:, None], 3, 1))
    np.testing.assert_allclose(ev("a", "Alpha"), 1.0)
    np.testing.assert_allclose(ev("c", "Fac"), attrs["color"].mean(1))   # Cycles: the average
    np.testing.assert_allclose(ev("m", "Fac"), 0.0)
    np.testing.assert_allclose(ev("m", "Color"), 0.0)
    np.testing.assert_allclose(ev("vi", "Density"), attrs["density"])
    np.testing.assert_allclose(ev("vi", "Color"), attrs["color"])
    np.testing.assert_allclose(ev("vi", "Flame"), 0.0)
    assert g.reads(graph, g.Link("vi", "Temperature")) == {"attribute:temperature"}
    assert g.attributes_read(graph, g.Link("a", "Fac")) == {"density"}


def test_unsupported_nodes_and_outputs_are_named():
    assert g.unsupported(g.Node("ShaderNodeTexBrick")) == "is not supported"
    assert "output 'Camera'" in g.unsupported(g.Node("ShaderNodeTexCoord"), "Camera")
    assert g.unsupported(g.Node("ShaderNodeTexCoord"), "Object") is None
    assert "ROTATION" in g.unsupported(g.Node("ShaderNodeMix", {"data_type": "ROTATION"}))
    assert "OBJECT" in g.unsupported(g.Node("ShaderNodeAttribute", {"attribute_type": "OBJECT"}))
    assert g.unsupported(g.Node("ShaderNodeMath", {"operation": "NOPE"})) is not None


def test_lattice_evaluation_matches_points_and_maps_the_texture_space():
    graph = g.Graph({"tc": g.Node("ShaderNodeTexCoord"),
                     "sep": g.Node("ShaderNodeSeparateXYZ", {},
                                   {"Vector": g.Link("tc", "Generated")}),
                     "geo": g.Node("ShaderNodeNewGeometry")})
    shape = (4, 3, 2)
    i2w = np.diag([0.5, 0.5, 0.5, 1.0])
    i2w[:3, 3] = (10.0, 0.0, 0.0)
    w2o = np.eye(4)
    w2o[:3, 3] = (-10.0, 0.0, 0.0)                            # object at x = 10
    tex = (np.array([-0.25, -0.25, -0.25]), np.array([1.75, 1.25, 0.75]))
    gen = g.evaluate_lattice(graph, g.Link("sep", "X"), "VALUE", shape, i2w, w2o, tex, chunk=5)
    i = np.arange(4)[:, None, None] * np.ones(shape)
    np.testing.assert_allclose(gen, (0.5 * i + 0.25) / 2.0, atol=1e-6)
    pos = g.evaluate_lattice(graph, g.Link("geo", "Position"), "VECTOR", shape, i2w, chunk=7)
    assert pos.shape == shape + (3,) and pos.dtype == np.float32
    np.testing.assert_allclose(pos[3, 2, 1], [11.5, 1.0, 0.5])


@pytest.mark.skipif(importlib.util.find_spec("mpp_render.textures.noise") is None,
                    reason="mpp_render.textures.noise not written yet")
def test_noise_node_calls_the_noise_texture_with_generated_by_default():
    from mpp_render.textures.noise import noise_texture
    pos = np.random.default_rng(1).random((50, 3)) * 4 - 2
    gen = pos * 0.25 + 0.5
    graph = g.Graph({"n": g.Node("ShaderNodeTexNoise",
                                 {"noise_dimensions": "3D", "noise_type": "FBM", "normalize": True},
                                 {"Scale": 2.0, "Detail": 3.0, "Roughness": 0.6,
                                  "Lacunarity": 2.0, "Distortion": 0.0})})
    out = g.evaluate(graph, g.Link("n", "Fac"), g.Points(pos, generated=gen))
    fac, _ = noise_texture(gen, scale=2.0, detail=3.0, roughness=0.6, color=False)
    np.testing.assert_allclose(out, fac, rtol=1e-6)
    assert g.reads(graph, g.Link("n", "Fac")) == {"generated"}


@pytest.mark.parametrize("kind, module, call", [
    ("ShaderNodeTexGradient", "gradient",
     lambda m, v: {"Fac": m.gradient_texture(v, gradient_type="QUADRATIC_SPHERE")}),
    ("ShaderNodeTexWave", "wave",
     lambda m, v: dict(zip(("Fac", "Color"), m.wave_texture(v, wave_type="RINGS", scale=3.0)))),
    ("ShaderNodeTexVoronoi", "voronoi",
     lambda m, v: m.voronoi_texture(v, feature="F2", scale=2.0, randomness=0.7)),
])
def test_texture_nodes_call_their_modules(kind, module, call):
    if importlib.util.find_spec(f"mpp_render.textures.{module}") is None:
        pytest.skip(f"mpp_render.textures.{module} not written yet")
    mod = importlib.import_module(f"mpp_render.textures.{module}")
    props = {"gradient_type": "QUADRATIC_SPHERE", "wave_type": "RINGS", "feature": "F2"}
    inputs = {"Scale": 3.0} if module == "wave" else {"Scale": 2.0, "Randomness": 0.7} \
        if module == "voronoi" else {}
    vec = np.random.default_rng(4).random((40, 3)) * 2 - 1
    graph = g.Graph({"t": g.Node(kind, props, dict(inputs, Vector=(0.0, 0.0, 0.0)))})
    graph.nodes["t"].inputs.pop("Vector")                  # unlinked: the Generated coordinates
    want = call(mod, vec)
    for out, values in want.items():
        got = g.evaluate(graph, g.Link("t", out), g.Points(vec * 9.0, generated=vec))
        np.testing.assert_allclose(got, values, rtol=1e-6, atol=1e-7, err_msg=out)
