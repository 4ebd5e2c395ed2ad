"""Our numpy Noise, Wave and White Noise (hash) textures against Blender's own.

Blender evaluates the nodes in a Geometry Nodes modifier on a point mesh (Position ->
texture node -> Store Named Attribute), read back from the evaluated mesh; the GN
multi-functions use BLI's noise code, which Cycles and EEVEE keep identical.  The points
are pseudo-random: most in [-3, 3]^3, some in [-1e3, 1e3]^3, [-3e4, 3e4]^3 (past the
100000 noise period once scaled) and [-3e5, 3e5]^3 (past the 1e6 precision correction),
a few on integer lattice points; W and some parameters are per-point attributes.

Tolerance: max abs error <= 1e-4 on Fac and Color for every variant (in practice the
numpy code reproduces Blender's float32 arithmetic and the errors are 0 or 1 ulp).
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.textures import hash as th  # noqa: E402
from mpp_render.textures.noise import noise_texture  # noqa: E402
from mpp_render.textures.wave import wave_texture  # noqa: E402

TOL = 1e-4
N = 2000
DIMS = ["1D", "2D", "3D", "4D"]
TYPES = ["FBM", "MULTIFRACTAL", "HYBRID_MULTIFRACTAL", "RIDGED_MULTIFRACTAL", "HETERO_TERRAIN"]


def _points():
    rng = np.random.default_rng(20250101)
    n_small = N - N // 4
    n_k, n_30k = N // 8, N // 16
    pos = np.concatenate([
        rng.uniform(-3, 3, (n_small, 3)),
        rng.uniform(-1e3, 1e3, (n_k, 3)),
        rng.uniform(-3e4, 3e4, (n_30k, 3)),
        rng.uniform(-3e5, 3e5, (N - n_small - n_k - n_30k, 3)),
    ]).astype(np.float32)
    pos[:16] = np.round(pos[:16])          # on the integer lattice (and negative integers)
    w = rng.uniform(-4, 4, N).astype(np.float32)
    w[N // 2: N // 2 + N // 8] *= 250      # large |W| too
    attrs = {
        "w_in": w,
        "detail_in": rng.uniform(-1, 17, N).astype(np.float32),  # clamping and fractions
        "rough_in": rng.uniform(-0.2, 1.3, N).astype(np.float32),
        "lac_in": rng.uniform(1.5, 3.0, N).astype(np.float32),
    }
    return pos, attrs


# (case name, node idname, node properties, socket inputs: a number or an attribute name)
def _noise_cases():
    cases = []
    for d in DIMS:
        for t in TYPES:
            cases.append((f"noise_{d}_{t}", "ShaderNodeTexNoise",
                          dict(noise_dimensions=d, noise_type=t, normalize=True),
                          dict(W="w_in", Scale=5.0, Detail=2.5, Roughness=0.6, Lacunarity=2.1,
                               Offset=0.3, Gain=1.2, Distortion=0.4)))
            cases.append((f"noisepp_{d}_{t}", "ShaderNodeTexNoise",
                          dict(noise_dimensions=d, noise_type=t, normalize=False),
                          dict(W="w_in", Scale=-3.0, Detail="detail_in", Roughness="rough_in",
                               Lacunarity="lac_in", Offset=1.0, Gain=2.0, Distortion=2.5)))
    for d in DIMS:  # integer detail (no blended octave), no distortion; detail 0
        cases.append((f"noiseint_{d}", "ShaderNodeTexNoise",
                      dict(noise_dimensions=d, noise_type="FBM", normalize=True),
                      dict(W="w_in", Scale=1.5, Detail=15.0, Roughness=0.9, Lacunarity=2.0,
                           Distortion=0.0)))
        cases.append((f"noisezero_{d}", "ShaderNodeTexNoise",
                      dict(noise_dimensions=d, noise_type="HETERO_TERRAIN", normalize=True),
                      dict(W="w_in", Scale=7.0, Detail=0.0, Roughness=0.0, Lacunarity=2.0,
                           Offset=-0.3, Distortion=-1.0)))
    return cases


def _wave_cases():
    cases = []
    for wt, dirs in (("BANDS", ["X", "Y", "Z", "DIAGONAL"]),
                     ("RINGS", ["X", "Y", "Z", "SPHERICAL"])):
        for dr in dirs:
            for pr in ("SIN", "SAW", "TRI"):
                props = dict(wave_type=wt, wave_profile=pr)
                props["bands_direction" if wt == "BANDS" else "rings_direction"] = dr
                cases.append((f"wave_{wt}_{dr}_{pr}", "ShaderNodeTexWave", props,
                              {"Scale": 2.0, "Distortion": 3.0, "Detail": "detail_in",
                               "Detail Scale": 1.5, "Detail Roughness": "rough_in",
                               "Phase Offset": 0.7}))
                cases.append((f"wave0_{wt}_{dr}_{pr}", "ShaderNodeTexWave", props,
                              {"Scale": 5.0, "Distortion": 0.0, "Detail": 2.0,
                               "Detail Scale": 1.0, "Detail Roughness": 0.5,
                               "Phase Offset": 0.0}))
    return cases


def _white_cases():
    return [(f"white_{d}", "ShaderNodeTexWhiteNoise", dict(noise_dimensions=d), dict(W="w_in"))
            for d in DIMS]


NOISE, WAVE, WHITE = _noise_cases(), _wave_cases(), _white_cases()


def _evaluate(pos, attrs, cases):
    """Blender's Fac/Value and Color of every case at the points (one GN tree)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    me = bpy.data.meshes.new("pts")
    me.vertices.add(len(pos))
    me.vertices.foreach_set("co", pos.ravel())
    for name, values in attrs.items():
        me.attributes.new(name, "FLOAT", "POINT").data.foreach_set("value", values)
    ob = bpy.data.objects.new("pts", me)
    bpy.context.scene.collection.objects.link(ob)

    ng = bpy.data.node_groups.new("textures", "GeometryNodeTree")
    ng.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    position = ng.nodes.new("GeometryNodeInputPosition").outputs[0]
    named = {}

    def attribute(name):
        if name not in named:
            node = ng.nodes.new("GeometryNodeInputNamedAttribute")
            node.data_type = "FLOAT"
            node.inputs["Name"].default_value = name
            named[name] = node.outputs["Attribute"]
        return named[name]

    geometry = gin.outputs[0]
    stores = []
    for cname, idname, props, inputs in cases:
        tex = ng.nodes.new(idname)
        for k, v in props.items():
            setattr(tex, k, v)
        if "Vector" in tex.inputs:
            ng.links.new(position, tex.inputs["Vector"])
        for k, v in inputs.items():
            if k not in tex.inputs:          # e.g. W in 2D/3D, Offset for fBm
                continue
            if isinstance(v, str):
                ng.links.new(attribute(v), tex.inputs[k])
            else:
                tex.inputs[k].default_value = v
        fac_name = "Value" if "Value" in tex.outputs else "Fac"
        for out, dtype in ((fac_name, "FLOAT"), ("Color", "FLOAT_COLOR")):
            st = ng.nodes.new("GeometryNodeStoreNamedAttribute")
            st.data_type, st.domain = dtype, "POINT"
            st.inputs["Name"].default_value = f"{cname}.{out}"
            ng.links.new(geometry, st.inputs["Geometry"])
            ng.links.new(tex.outputs[out], st.inputs["Value"])
            geometry = st.outputs["Geometry"]
            stores.append((cname, out, dtype))
    ng.links.new(geometry, gout.inputs[0])
    ob.modifiers.new("textures", "NODES").node_group = ng

    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    result = {}
    n = len(pos)
    for cname, out, dtype in stores:
        data = ev.attributes[f"{cname}.{out}"].data
        if dtype == "FLOAT":
            arr = np.empty(n, np.float32)
            data.foreach_get("value", arr)
        else:
            arr = np.empty(n * 4, np.float32)
            data.foreach_get("color", arr)
            arr = arr.reshape(n, 4)[:, :3]
        result.setdefault(cname, {})["fac" if out != "Color" else "color"] = arr
    return result


@pytest.fixture(scope="module")
def blender():
    pos, attrs = _points()
    return pos, attrs, _evaluate(pos, attrs, NOISE + WAVE + WHITE)


def _value(v, attrs):
    return attrs[v] if isinstance(v, str) else v


def _check(ours, theirs, name):
    fac, color = ours
    ef = float(np.abs(fac - theirs["fac"]).max())
    ec = float(np.abs(color - theirs["color"]).max())
    assert np.isfinite(theirs["fac"]).all()
    assert ef <= TOL and ec <= TOL, f"{name}: max |fac err| {ef:.3g}, max |color err| {ec:.3g}"


@pytest.mark.parametrize("case", NOISE, ids=[c[0] for c in NOISE])
def test_noise_texture_matches_blender(blender, case):
    pos, attrs, ref = blender
    cname, _, props, inp = case
    v = {k: _value(x, attrs) for k, x in inp.items()}
    ours = noise_texture(pos, w=v["W"], dimensions=props["noise_dimensions"],
                         noise_type=props["noise_type"], normalize=props["normalize"],
                         scale=v["Scale"], detail=v["Detail"], roughness=v["Roughness"],
                         lacunarity=v["Lacunarity"], offset=v.get("Offset", 0.0),
                         gain=v.get("Gain", 1.0), distortion=v["Distortion"])
    _check(ours, ref[cname], cname)


@pytest.mark.parametrize("case", WAVE, ids=[c[0] for c in WAVE])
def test_wave_texture_matches_blender(blender, case):
    pos, attrs, ref = blender
    cname, _, props, inp = case
    v = {k: _value(x, attrs) for k, x in inp.items()}
    ours = wave_texture(pos, scale=v["Scale"], distortion=v["Distortion"], detail=v["Detail"],
                        detail_scale=v["Detail Scale"], detail_roughness=v["Detail Roughness"],
                        phase_offset=v["Phase Offset"], **props)
    _check(ours, ref[cname], cname)


@pytest.mark.parametrize("case", WHITE, ids=[c[0] for c in WHITE])
def test_float_hashes_match_blender_white_noise(blender, case):
    """White Noise = hash_float_to_float / hash_float_to_float3 of (w), (x, y), (x, y, z),
    (x, y, z, w): checks our hashes bit for bit against Blender's."""
    pos, attrs, ref = blender
    cname, _, props, _ = case
    w = attrs["w_in"]
    d = props["noise_dimensions"]
    if d == "1D":
        value, color = th.hash_float_to_float(w), th.hash_float_to_float3(w)
    elif d == "2D":
        value, color = th.hash_float2_to_float(pos[:, :2]), th.hash_float2_to_float3(pos[:, :2])
    elif d == "3D":
        value, color = th.hash_float3_to_float(pos), th.hash_float3_to_float3(pos)
    else:
        p4 = np.concatenate([pos, w[:, None]], axis=1)
        value, color = th.hash_float4_to_float(p4), th.hash_float4_to_float3(p4)
    np.testing.assert_array_equal(value, ref[cname]["fac"])
    np.testing.assert_array_equal(color, ref[cname]["color"])
