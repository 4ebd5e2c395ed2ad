"""The numpy Voronoi and Gradient textures against Blender's own, evaluated by Geometry Nodes.

Geometry Nodes evaluates the shader texture nodes with the BLI noise code that Blender keeps
identical to Cycles' SVM kernels, so it is the reference: a mesh of a few thousand vertices
at pseudo-random positions (negative and large-ish coordinates among them) carries a
Geometry Nodes modifier Position -> texture node -> Store Named Attribute (POINT domain,
FLOAT / FLOAT_VECTOR / FLOAT_COLOR); the evaluated mesh's attributes are read back with
``foreach_get`` and compared with ``mpp_render.textures``: max abs error <= 1e-4 per output.

Linked (per-point) inputs come from point attributes read by Named Attribute nodes.  All
variants live in one node tree evaluated once (module fixture, built from
``read_factory_settings(use_empty=True)``); each test then compares one variant.  Geometry
Nodes leaves Detail and Roughness unclamped (Cycles clamps them), so the variants with those
out of range use ``clamp_inputs=False``; the Gradient's factor is clamped in both.
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.textures.gradient import GRADIENT_TYPES, gradient_outputs  # noqa: E402
from mpp_render.textures.voronoi import voronoi_texture  # noqa: E402

TOL = 1e-4  # every point, every output component (measured: 0, bit for bit, in 5.0.1)
N = 2400
GRADIENT_SCALE = 0.3  # the gradients see Position * 0.3: most points in [-1.2, 1.2]^3

OUTPUT_TYPES = {"Distance": "FLOAT", "W": "FLOAT", "Radius": "FLOAT",
                "Position": "FLOAT_VECTOR", "Color": "FLOAT_COLOR",
                "Fac": "FLOAT"}


def points():
    """N positions: most in [-4, 4]^3, a tenth out to +-300; plus per-point inputs."""
    rng = np.random.default_rng(20240917)
    co = rng.uniform(-4.0, 4.0, (N, 3))
    far = rng.random(N) < 0.1
    co[far] = rng.uniform(-300.0, 300.0, (far.sum(), 3))
    co = co.astype(np.float32)
    attrs = {
        "in_w": rng.uniform(-5.0, 5.0, N),
        "in_detail": rng.uniform(0.0, 3.0, N),
        "in_rough": rng.uniform(0.0, 1.0, N),
        "in_lac": rng.uniform(1.5, 3.0, N),
        "in_rand": rng.uniform(0.0, 1.0, N),
        "in_smooth": np.where(rng.random(N) < 0.1, 0.0, rng.uniform(0.0, 1.0, N)),
        "in_scale": rng.uniform(-6.0, 6.0, N),
        "in_exp": rng.uniform(0.3, 4.0, N),
        "in_detail_wide": rng.uniform(-1.0, 18.0, N),
        "in_rough_wide": rng.uniform(0.0, 1.5, N),
    }
    return co, {k: v.astype(np.float32) for k, v in attrs.items()}


V_SOCKETS = {"w": "W", "scale": "Scale", "detail": "Detail", "roughness": "Roughness",
             "lacunarity": "Lacunarity", "smoothness": "Smoothness", "exponent": "Exponent",
             "randomness": "Randomness"}


def voronoi_variants():
    """(name, node settings, inputs); an input that is a str names a point attribute."""
    out = []
    base = {"w": "in_w", "scale": 1.7}
    for dims in ("1D", "2D", "3D", "4D"):
        for feature in ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS"):
            out.append((f"{dims}_{feature}", dict(dims=dims, feature=feature),
                        dict(base, smoothness=0.6, randomness=0.9)))
    for dims in ("2D", "3D", "4D"):
        for metric in ("MANHATTAN", "CHEBYCHEV", "MINKOWSKI"):
            for feature in ("F1", "F2", "SMOOTH_F1"):
                if dims == "4D" and feature == "SMOOTH_F1" and metric != "MINKOWSKI":
                    continue  # 625 cells: keep the file quick
                out.append((f"{dims}_{feature}_{metric}",
                            dict(dims=dims, feature=feature, distance=metric),
                            dict(base, smoothness=0.8, exponent=1.6)))
    # Per-point exponent for Minkowski.
    out.append(("3D_F1_MINKOWSKI_exp", dict(dims="3D", feature="F1", distance="MINKOWSKI"),
                dict(base, exponent="in_exp")))
    # Fractal: fractional per-point detail, roughness, lacunarity; normalize on and off.
    fractal = dict(base, detail="in_detail", roughness="in_rough", lacunarity="in_lac")
    for dims in ("1D", "2D", "3D", "4D"):
        for feature in ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE"):
            if dims == "4D" and feature == "SMOOTH_F1":
                continue
            for norm in (False, True):
                out.append((f"{dims}_{feature}_fractal{'_norm' if norm else ''}",
                            dict(dims=dims, feature=feature, normalize=norm),
                            dict(fractal, smoothness=0.5)))
    out.append(("4D_SMOOTH_F1_fractal_norm", dict(dims="4D", feature="SMOOTH_F1", normalize=True),
                dict(base, detail=1.25, roughness=0.6, lacunarity=2.5, smoothness=0.4)))
    out.append(("3D_F1_MANHATTAN_fractal_norm",
                dict(dims="3D", feature="F1", distance="MANHATTAN", normalize=True),
                dict(fractal)))
    out.append(("2D_F2_MINKOWSKI_fractal_norm",
                dict(dims="2D", feature="F2", distance="MINKOWSKI", normalize=True),
                dict(fractal, exponent=0.7)))
    # Per-point randomness, smoothness (some 0), scale (negative too); randomness 0.
    for feature in ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS"):
        out.append((f"3D_{feature}_perpoint", dict(dims="3D", feature=feature),
                    dict(base, scale="in_scale", randomness="in_rand",
                         smoothness="in_smooth")))
        out.append((f"2D_{feature}_regular", dict(dims="2D", feature=feature),
                    dict(base, randomness=0.0, smoothness=0.3)))
    out.append(("1D_SMOOTH_F1_perpoint", dict(dims="1D", feature="SMOOTH_F1"),
                dict(base, scale="in_scale", randomness="in_rand", smoothness="in_smooth")))
    out.append(("4D_F1_perpoint", dict(dims="4D", feature="F1"),
                dict(base, scale="in_scale", randomness="in_rand", detail="in_detail")))
    # Geometry Nodes does not clamp Detail and Roughness (Cycles does): clamp_inputs=False.
    wide = dict(base, detail="in_detail_wide", roughness="in_rough_wide", lacunarity=1.9)
    for feature in ("F1", "DISTANCE_TO_EDGE"):
        out.append((f"2D_{feature}_unclamped",
                    dict(dims="2D", feature=feature, normalize=True, clamp=False), wide))
    # Minkowski exponent 0: every distance is infinite.
    out.append(("3D_F1_MINKOWSKI_exp0", dict(dims="3D", feature="F1", distance="MINKOWSKI"),
                dict(base, exponent=0.0)))
    return out


VORONOI = voronoi_variants()


def _new_tree():
    tree = bpy.data.node_groups.new("textures", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin = tree.nodes.new("NodeGroupInput")
    gout = tree.nodes.new("NodeGroupOutput")
    pos = tree.nodes.new("GeometryNodeInputPosition")
    return tree, gin, gout, pos


class _Chain:
    """Store Named Attribute nodes chained on the geometry."""

    def __init__(self, tree, gin):
        self.tree, self.geo, self.stored = tree, gin.outputs[0], []
        self.readers = {}

    def attribute(self, name):
        if name not in self.readers:
            node = self.tree.nodes.new("GeometryNodeInputNamedAttribute")
            node.data_type = "FLOAT"
            node.inputs["Name"].default_value = name
            self.readers[name] = node.outputs["Attribute"]
        return self.readers[name]

    def store(self, name, socket, data_type):
        node = self.tree.nodes.new("GeometryNodeStoreNamedAttribute")
        node.data_type, node.domain = data_type, "POINT"
        node.inputs["Name"].default_value = name
        self.tree.links.new(self.geo, node.inputs["Geometry"])
        self.tree.links.new(socket, node.inputs["Value"])
        self.geo = node.outputs["Geometry"]
        self.stored.append((name, data_type))


def _read(mesh, name, data_type):
    attr = mesh.attributes[name]
    width = {"FLOAT": 1, "FLOAT_VECTOR": 3, "FLOAT_COLOR": 4}[data_type]
    key = {"FLOAT": "value", "FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color"}[data_type]
    buf = np.empty(len(attr.data) * width, np.float32)
    attr.data.foreach_get(key, buf)
    return buf.reshape(-1, width)[:, :3] if width > 1 else buf


@pytest.fixture(scope="module")
def blender():
    """Every variant evaluated by Geometry Nodes: (positions, inputs, {attr name: array})."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    co, attrs = points()
    mesh = bpy.data.meshes.new("pts")
    mesh.vertices.add(N)
    mesh.vertices.foreach_set("co", co.ravel())
    for name, values in attrs.items():
        mesh.attributes.new(name, "FLOAT", "POINT").data.foreach_set("value", values)
    mesh.update()
    ob = bpy.data.objects.new("pts", mesh)
    bpy.context.scene.collection.objects.link(ob)

    tree, gin, gout, pos = _new_tree()
    chain = _Chain(tree, gin)
    for name, opts, inputs in VORONOI:
        node = tree.nodes.new("ShaderNodeTexVoronoi")
        node.voronoi_dimensions = opts["dims"]
        node.feature = opts["feature"]
        node.distance = opts.get("distance", "EUCLIDEAN")
        node.normalize = opts.get("normalize", False)
        if opts["dims"] != "1D":
            tree.links.new(pos.outputs["Position"], node.inputs["Vector"])
        for key, value in inputs.items():
            sock = node.inputs.get(V_SOCKETS[key])
            if sock is None or not sock.enabled:
                continue  # not shown for this feature / dimension
            if isinstance(value, str):
                tree.links.new(chain.attribute(value), sock)
            else:
                sock.default_value = value
        for out in node.outputs:
            if out.enabled:
                chain.store(f"{name}:{out.name}", out, OUTPUT_TYPES[out.name])
    shrink = tree.nodes.new("ShaderNodeVectorMath")  # most points inside the unit ball
    shrink.operation = "SCALE"
    shrink.inputs["Scale"].default_value = GRADIENT_SCALE
    tree.links.new(pos.outputs["Position"], shrink.inputs[0])
    for gtype in GRADIENT_TYPES:
        node = tree.nodes.new("ShaderNodeTexGradient")
        node.gradient_type = gtype
        tree.links.new(shrink.outputs["Vector"], node.inputs["Vector"])
        chain.store(f"grad_{gtype}:Fac", node.outputs["Fac"], "FLOAT")
        chain.store(f"grad_{gtype}:Color", node.outputs["Color"], "FLOAT_COLOR")
    tree.links.new(chain.geo, gout.inputs[0])
    mod = ob.modifiers.new("textures", "NODES")
    mod.node_group = tree

    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = ob.evaluated_get(depsgraph).data
    got = {name: _read(evaluated, name, dt) for name, dt in chain.stored}
    return co, attrs, got


def _ours(co, attrs, opts, inputs):
    kw = {k: (attrs[v] if isinstance(v, str) else v) for k, v in inputs.items()}
    return voronoi_texture(co, dimensions=opts["dims"], feature=opts["feature"],
                           distance=opts.get("distance", "EUCLIDEAN"),
                           normalize=opts.get("normalize", False),
                           clamp_inputs=opts.get("clamp", True), **kw)


def max_error(ours, theirs):
    """Largest |ours - theirs| (equal infinities count as 0, any NaN as inf)."""
    ours = np.asarray(ours, np.float64)
    with np.errstate(invalid="ignore"):
        err = np.where(ours == theirs, 0.0, np.abs(ours - theirs))
    return float(np.nan_to_num(err, nan=np.inf).max())


def _compare(name, ours, theirs):
    err = max_error(ours, theirs)
    assert err <= TOL, f"{name}: max abs error {err:.3g} > {TOL}"


@pytest.mark.parametrize("name,opts,inputs", VORONOI, ids=[v[0] for v in VORONOI])
def test_voronoi_matches_geometry_nodes(blender, name, opts, inputs):
    co, attrs, got = blender
    ours = _ours(co, attrs, opts, inputs)
    theirs = {k.split(":")[1]: v for k, v in got.items() if k.split(":")[0] == name}
    assert set(ours) == set(theirs), (sorted(ours), sorted(theirs))
    for out, value in ours.items():
        _compare(f"{name}:{out}", value, theirs[out])


@pytest.mark.parametrize("gtype", GRADIENT_TYPES)
def test_gradient_matches_geometry_nodes(blender, gtype):
    """Fac and Color (Fac as grey), both clamped to [0, 1] as in Cycles."""
    co, _, got = blender
    ours = gradient_outputs(co * np.float32(GRADIENT_SCALE), gtype)
    _compare(f"{gtype}:Fac", ours["Fac"], got[f"grad_{gtype}:Fac"])
    _compare(f"{gtype}:Color", ours["Color"], got[f"grad_{gtype}:Color"])
