"""Fluid (Mantaflow) smoke domains: baked OpenVDB cache frames in Blender's layout are read,
placed in the domain's world bounds and shaded by its material; missing, corrupt and
oversized frames are reported by file name; the reader process has a time limit.

Mantaflow cannot simulate in the bpy module and a scene holding a domain aborts the
interpreter at exit (blender-notes), so every scene with a domain is built in a subprocess
that ends with ``os._exit(0)``; it prints ``RESULT <json>`` lines that the tests check.  The
cache frames are written here with the openvdb module, as Mantaflow writes them: one file per
frame, ``<cache>/data/fluid_data_####.vdb`` (and ``noise/fluid_noise_####.vdb``), grids
'density', 'flame', 'temperature' (Mantaflow's heat), 'color_r/g/b', index (0,0,0) at the
domain's first cell, voxel size = domain size / resolution."""
import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))

# The domain of every test: a 2 x 1 x 1 m box (a default cube scaled (1, 0.5, 0.5)) at (1, 2, 3)
# with resolution_max 32, so 32 x 16 x 16 cells of 0.0625 m from (0, 1.5, 2.5) to (2, 2.5, 3.5).
LOCATION = (1.0, 2.0, 3.0)
SCALE = (1.0, 0.5, 0.5)
RES = (32, 16, 16)
LO = np.array([0.0, 1.5, 2.5])
CELL = 2.0 / 32


def cell_centre(ijk, cell=CELL):
    return LO + (np.asarray(ijk, float) + 0.5) * cell


# -- helpers used inside the subprocesses (``import test_fluid as t``) --------------------------

def plume(shape, centre, radius=2.0):
    """A Gaussian puff (peak 1 at cell ``centre``) on a grid of ``shape`` cells."""
    ii = np.indices(shape).astype(np.float32)
    r2 = sum((ii[a] - centre[a]) ** 2 for a in range(3))
    d = np.exp(-r2 / (2 * radius ** 2)).astype(np.float32)
    d[d < 1e-3] = 0.0
    return d


def write_frame(path, grids, voxel=CELL):
    """A cache frame holding ``grids`` (name -> float32 array placed at ijk (0,0,0))."""
    from mpp_render.blender.translate.vdb import openvdb_module
    vdb = openvdb_module()
    out = []
    for name, a in grids.items():
        g = vdb.FloatGrid()
        g.copyFromArray(np.ascontiguousarray(a, np.float32))
        g.name = name
        g.transform = vdb.createLinearTransform(voxelSize=voxel)
        out.append(g)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    vdb.write(path, grids=out)


def volume_material(name="Smoke", density=5.0, attribute="density", color=(0.9, 0.9, 0.9),
                    color_attribute=""):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Density"].default_value = density
    pv.inputs["Density Attribute"].default_value = attribute
    pv.inputs["Color"].default_value = (*color, 1.0)
    pv.inputs["Color Attribute"].default_value = color_attribute
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    return mat


def fire_material(name="Fire", density=10.0, blackbody=1.0, temperature_attribute="temperature",
                  strength_attribute=None, emission_color=(1.0, 0.5, 0.25)):
    """The usual fire shader: a Principled Volume on the 'density' grid with blackbody
    emission (Temperature 1000 K x the grid ``temperature_attribute``); with
    ``strength_attribute`` an Attribute node reading that grid drives Emission Strength
    (Emission Color ``emission_color``)."""
    mat = volume_material(name, density=density)
    nt = mat.node_tree
    pv = nt.nodes["Principled Volume"]
    pv.inputs["Blackbody Intensity"].default_value = blackbody
    pv.inputs["Temperature"].default_value = 1000.0
    pv.inputs["Temperature Attribute"].default_value = temperature_attribute
    if strength_attribute is not None:
        attr = nt.nodes.new("ShaderNodeAttribute")
        attr.attribute_name = strength_attribute
        nt.links.new(attr.outputs["Fac"], pv.inputs["Emission Strength"])
        pv.inputs["Emission Color"].default_value = (*emission_color, 1.0)
    return mat


def emission_material(attribute, color=(1.0, 0.5, 0.25)):
    """An Emission shader alone whose Strength an Attribute node reading ``attribute`` drives."""
    mat = bpy.data.materials.new("Glow")
    nt = mat.node_tree
    nt.nodes.clear()
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*color, 1.0)
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = attribute
    nt.links.new(attr.outputs["Fac"], em.inputs["Strength"])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(em.outputs[0], out.inputs["Volume"])
    return mat


def emission_at(m, point):
    """A medium's per-voxel emission (RGB) at its lattice point nearest the world ``point``
    (None: no emission grid; zeros: outside the medium's cropped block)."""
    if m.emission_grid is None:
        return None
    local = np.rint(np.linalg.inv(m.index_to_world) @ [*point, 1])[:3].astype(int)
    if np.any(local < 0) or np.any(local >= m.density.shape):
        return [0.0, 0.0, 0.0]
    return m.emission_grid[tuple(local)].tolist()


def domain(cache_dir, material=None, cache_type="MODULAR", end=10, offset=0, noise=0):
    """The test domain (see LOCATION/SCALE) pointed at ``cache_dir``; returns its object."""
    bpy.ops.mesh.primitive_cube_add(location=LOCATION)
    ob = bpy.context.object
    ob.name = "Smoke"
    ob.scale = SCALE
    mod = ob.modifiers.new("Fluid", "FLUID")
    mod.fluid_type = "DOMAIN"
    d = mod.domain_settings
    d.resolution_max = 32
    d.cache_type = cache_type
    d.cache_directory = cache_dir
    d.cache_frame_start, d.cache_frame_end = 1, end
    d.cache_frame_offset = offset
    if noise:
        d.use_noise = True
        d.noise_scale = noise
    if material is not None:
        ob.data.materials.append(material)
    return ob


def translate(frame, resolution=16):
    from mpp_render.blender.translate import scene_from_depsgraph
    from mpp_render.scene import Settings
    bpy.context.scene.frame_set(frame)
    return scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(),
                                Settings(voxel_resolution=resolution))


def medium_record(m):
    """What the tests check of a medium: its cells' world centres and values."""
    d = m.density
    peak = np.unravel_index(int(np.argmax(d)), d.shape)
    return {"name": m.name, "source": m.source, "shape": list(d.shape),
            "sum": float(d.sum(dtype=np.float64)), "max": float(d.max()),
            "peak_world": (m.index_to_world @ [*peak, 1])[:3].tolist(),
            "origin_world": (m.index_to_world @ [0, 0, 0, 1])[:3].tolist(),
            "cell": np.linalg.norm(m.index_to_world[:3, :3], axis=0).tolist(),
            "sigma_s": np.asarray(m.sigma_s).tolist(), "sigma_a": np.asarray(m.sigma_a).tolist(),
            "emission": np.asarray(m.emission).tolist(),
            "scatter": None if m.scatter_grid is None else {
                # the factor on sigma_s (Medium.scatter_grid) at the densest cell, and its
                # density-weighted mean (1: sigma_s is the mean)
                "peak": m.scatter_grid[peak].tolist(),
                "mean": (np.einsum("xyz,xyzc->c", d.astype(np.float64), m.scatter_grid)
                         / d.sum(dtype=np.float64)).tolist()}}


def report(tag, desc):
    print("RESULT", json.dumps({"tag": tag, "media": [medium_record(m) for m in desc.media],
                                "warnings": desc.warnings}), flush=True)


# -- the subprocess runner --------------------------------------------------------------------

def run(body, tmp_path, env=None, timeout=240):
    """Run ``body`` in a fresh interpreter with bpy, this module as ``t`` and ``CACHE`` (a
    folder for the cache frames); returns the RESULT records by tag."""
    script = textwrap.dedent("""
        import json, os, sys
        sys.path.insert(0, {repo!r})
        sys.path.insert(0, {here!r})
        import numpy as np
        import bpy
        import test_fluid as t
        CACHE = {cache!r}
        bpy.ops.wm.read_factory_settings(use_empty=True)
        try:
    """).format(repo=REPO, here=HERE, cache=str(tmp_path / "cache"))
    script += textwrap.indent(textwrap.dedent(body), "    ")
    script += textwrap.dedent("""
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)
    """)
    full_env = dict(os.environ)
    full_env.update(env or {})
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=timeout, cwd=str(tmp_path), env=full_env)
    out = {}
    for line in p.stdout.splitlines():
        if line.startswith("RESULT "):
            rec = json.loads(line[7:])
            out[rec["tag"]] = rec
    assert out, f"no result (rc {p.returncode}):\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    return out


def only(rec):
    assert len(rec["media"]) == 1, rec
    return rec["media"][0]


def warned(rec, *parts):
    hits = [w for w in rec["warnings"] if all(p in w for p in parts)]
    assert hits, f"no warning with {parts}: {rec['warnings']}"
    return hits


# -- tests ------------------------------------------------------------------------------------

def test_cache_frames_are_placed_in_the_domain_bounds(tmp_path):
    body = """
        ob = t.domain(CACHE, t.volume_material(density=5.0))
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": t.plume(t.RES, (24, 8, 8))})
        t.write_frame(CACHE + "/data/fluid_data_0002.vdb", {"density": 0.5 * t.plume(t.RES, (4, 3, 12))})
        t.report("f1", t.translate(1))
        t.report("f2", t.translate(2))
        t.report("f1_again", t.translate(1))
        from mpp_render import cache
        print("RESULT", json.dumps({"tag": "cache", "stats": cache.CACHE.stats()}))
    """
    r = run(body, tmp_path, env={"MPP_CACHE_MB": "64"})
    m1, m2 = only(r["f1"]), only(r["f2"])
    assert m1["source"] == "FLUID" and m1["name"] == "Smoke"
    # the puff's peak cell lands on its cell centre in the world: domain (0,1.5,2.5)..(2,2.5,3.5)
    np.testing.assert_allclose(m1["peak_world"], cell_centre((24, 8, 8)), atol=1e-9)
    np.testing.assert_allclose(m2["peak_world"], cell_centre((4, 3, 12)), atol=1e-9)
    np.testing.assert_allclose(m1["cell"], [CELL] * 3, rtol=1e-12)
    want = t_plume_sum((24, 8, 8))
    assert m1["sum"] == pytest.approx(want, rel=1e-6) and m1["max"] == pytest.approx(1.0)
    assert m2["max"] == pytest.approx(0.5)
    # Principled Volume: colour 0.9, density 5, per unit of the 'density' grid
    np.testing.assert_allclose(m1["sigma_s"], [4.5] * 3, rtol=1e-6)
    np.testing.assert_allclose(m1["sigma_a"], [0.5] * 3, rtol=1e-5)
    assert not [w for w in r["f1"]["warnings"] if "Smoke" in w]
    # frame 1 read again: taken from the cache, the same medium
    assert only(r["f1_again"]) == m1
    stats = r["cache"]["stats"]
    assert stats["hits"].get("fluid", 0) >= 1 and stats["misses"].get("fluid", 0) == 2


def t_plume_sum(centre):
    return float(plume(RES, centre).sum(dtype=np.float64))


def test_frame_offset_and_replay_cache_type(tmp_path):
    # (Blender frees a domain's cache when its cache type changes: one scene per type, the
    # frames written after the domain is made)
    body = """
        ob = t.domain(CACHE, t.volume_material(), offset=2)   # modular: scene 5 shows frame 3
        t.write_frame(CACHE + "/data/fluid_data_0003.vdb", {"density": t.plume(t.RES, (10, 8, 8))})
        t.report("modular5", t.translate(5))
        bpy.ops.wm.read_factory_settings(use_empty=True)
        ob = t.domain(CACHE + "2", t.volume_material(), offset=2, cache_type="REPLAY")
        t.write_frame(CACHE + "2/data/fluid_data_0003.vdb", {"density": t.plume(t.RES, (10, 8, 8))})
        t.report("replay3", t.translate(3))  # replay ignores the offset
        t.report("replay5", t.translate(5))
    """
    r = run(body, tmp_path)
    np.testing.assert_allclose(only(r["modular5"])["peak_world"], cell_centre((10, 8, 8)), atol=1e-9)
    np.testing.assert_allclose(only(r["replay3"])["peak_world"], cell_centre((10, 8, 8)), atol=1e-9)
    assert r["replay5"]["media"] == []
    warned(r["replay5"], "'Smoke'", "fluid_data_0005.vdb", "not found")


def test_missing_corrupt_truncated_and_out_of_range_frames_are_reported(tmp_path):
    body = """
        ob = t.domain(CACHE, t.volume_material(), end=6)
        good = CACHE + "/data/fluid_data_0001.vdb"
        t.write_frame(good, {"density": t.plume(t.RES, (16, 8, 8))})
        data = open(good, "rb").read()
        open(CACHE + "/data/fluid_data_0003.vdb", "wb").write(
            np.random.default_rng(2).integers(0, 256, 4096, dtype=np.uint8).tobytes())
        open(CACHE + "/data/fluid_data_0004.vdb", "wb").write(data[:len(data) // 2])
        open(CACHE + "/data/fluid_data_0005.vdb", "wb").write(b"")
        for f in (2, 3, 4, 5, 7, 1):
            t.report(f"f{f}", t.translate(f))
    """
    r = run(body, tmp_path)
    for f in (2, 3, 4, 5, 7):
        assert r[f"f{f}"]["media"] == [], f
    warned(r["f2"], "'Smoke'", "fluid_data_0002.vdb", "not found")
    for f in (3, 4, 5):
        msgs = warned(r[f"f{f}"], "'Smoke'", f"fluid_data_000{f}.vdb")
        assert any("corrupt" in m or "could not be read" in m for m in msgs), msgs
    warned(r["f7"], "'Smoke'", "outside its cache frames 1..6")
    assert only(r["f1"])["max"] == pytest.approx(1.0)  # a good frame still renders


def test_grid_beyond_the_domain_is_cut_with_a_warning(tmp_path):
    body = """
        ob = t.domain(CACHE, t.volume_material())
        big = np.zeros((40, 16, 16), np.float32)
        big[30:38, 6:10, 6:10] = 1.0   # cells 32..37 lie beyond the domain's 32
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": big})
        t.report("f1", t.translate(1))
    """
    r = run(body, tmp_path)
    m = only(r["f1"])
    assert m["shape"] == [2, 4, 4] and m["sum"] == pytest.approx(32.0)
    np.testing.assert_allclose(m["origin_world"], cell_centre((30, 6, 6)), atol=1e-9)
    warned(r["f1"], "'Smoke'", "'density'", "reaches outside", "fluid_data_0001.vdb")


def test_noise_flame_heat_temperature_and_colour(tmp_path):
    body = """
        mat = t.volume_material(color=(1.0, 1.0, 1.0), color_attribute="color")
        ob = t.domain(CACHE, mat, noise=2)
        res2 = tuple(2 * n for n in t.RES)
        dens = t.plume(t.RES, (8, 8, 8))
        flame = 0.8 * t.plume(t.RES, (20, 8, 8))
        heat = 1.6 * t.plume(t.RES, (12, 8, 8))
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb",
                      {"density": dens, "flame": flame, "temperature": heat})
        nd = t.plume(res2, (17, 16, 16), radius=4.0)
        t.write_frame(CACHE + "/noise/fluid_noise_0001.vdb",
                      {"density_noise": nd, "flame_noise": 0.8 * t.plume(res2, (41, 16, 16), 4.0),
                       "color_r_noise": 0.2 * nd, "color_g_noise": 0.4 * nd,
                       "color_b_noise": 0.8 * nd}, voxel=t.CELL / 2)
        t.report("noise", t.translate(1))
        for attr in ("flame", "heat", "temperature"):
            ob.data.materials.clear()
            ob.data.materials.append(t.volume_material(f"M{attr}", density=1.0, attribute=attr))
            t.report(attr, t.translate(1))
        os.remove(CACHE + "/noise/fluid_noise_0001.vdb")
        ob.data.materials.clear()
        ob.data.materials.append(t.volume_material("Plain"))
        t.report("no_noise_file", t.translate(1))
    """
    r = run(body, tmp_path)
    # noise: density at twice the resolution, tinted by the smoke colour (0.2, 0.4, 0.8)
    m = only(r["noise"])
    np.testing.assert_allclose(m["cell"], [CELL / 2] * 3, rtol=1e-12)
    np.testing.assert_allclose(m["peak_world"], LO + (np.array([17, 16, 16]) + 0.5) * CELL / 2,
                               atol=1e-9)
    np.testing.assert_allclose(m["sigma_s"], [1.0, 2.0, 4.0], rtol=1e-5)  # 5 x colour
    np.testing.assert_allclose(m["sigma_a"], [4.0, 3.0, 1.0], rtol=1e-5)  # 5 x (1 - colour)
    assert not [w for w in r["noise"]["warnings"] if "Color Attribute" in w]
    # flame from the noise file; heat (low resolution, x 0.5); temperature from flame
    fl = only(r["flame"])
    np.testing.assert_allclose(fl["peak_world"], LO + (np.array([41, 16, 16]) + 0.5) * CELL / 2,
                               atol=1e-9)
    assert fl["max"] == pytest.approx(0.8, rel=1e-3)
    he = only(r["heat"])
    np.testing.assert_allclose(he["cell"], [CELL] * 3, rtol=1e-12)
    np.testing.assert_allclose(he["peak_world"], cell_centre((12, 8, 8)), atol=1e-9)
    assert he["max"] == pytest.approx(0.8, rel=1e-4)
    te = only(r["temperature"])  # ignition 1.5 + flame (3.0 - 1.5) where flame > 0.01
    assert te["max"] == pytest.approx(1.5 + 0.8 * 1.5, rel=1e-3)
    np.testing.assert_allclose(te["peak_world"], fl["peak_world"], atol=1e-9)
    # the noise frame missing: the low-resolution data with a warning naming the file
    lo_res = only(r["no_noise_file"])
    np.testing.assert_allclose(lo_res["peak_world"], cell_centre((8, 8, 8)), atol=1e-9)
    warned(r["no_noise_file"], "'Smoke'", "fluid_noise_0001.vdb", "not found")


def test_smoke_colour_varies_per_voxel(tmp_path):
    """Color Attribute 'color' multiplies the Color by the smoke colour voxel by voxel
    (Medium.scatter_grid over the density-weighted mean): two puffs, orange and blue."""
    body = """
        mat = t.volume_material(color=(1.0, 1.0, 1.0), color_attribute="color")
        ob = t.domain(CACHE, mat)
        a = t.plume(t.RES, (8, 8, 8))
        b = t.plume(t.RES, (24, 8, 8))
        dens = a + b
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb",
                      {"density": dens, "color_r": 0.9 * a + 0.1 * b,
                       "color_g": 0.5 * a + 0.4 * b, "color_b": 0.1 * a + 0.8 * b})
        t.report("two", t.translate(1))
    """
    r = run(body, tmp_path)
    rec = r["two"]
    assert not [w for w in rec["warnings"] if "colour" in w or "Color" in w], rec["warnings"]
    m = only(rec)
    sc = m["scatter"]
    assert sc is not None
    np.testing.assert_allclose(sc["mean"], [1.0, 1.0, 1.0], rtol=1e-4)
    # sigma_s: 5 x the mean colour; the puffs are alike, so the mean is about the average
    np.testing.assert_allclose(m["sigma_s"], 5.0 * np.array([0.5, 0.45, 0.45]), rtol=0.05)
    # the densest cell lies in one puff: its colour over the mean, orange or blue
    colour = np.array(sc["peak"]) * np.array(m["sigma_s"]) / 5.0
    assert (np.allclose(colour, [0.9, 0.5, 0.1], atol=0.02)
            or np.allclose(colour, [0.1, 0.4, 0.8], atol=0.02)), colour
    # the extinction is the density's, whatever the colour (a black Absorption Color)
    np.testing.assert_allclose(np.add(m["sigma_s"], m["sigma_a"]), 5.0, rtol=1e-5)


def test_domain_shading_without_material_with_uniform_shaders_and_emission(tmp_path):
    body = """
        ob = t.domain(CACHE)
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": t.plume(t.RES, (16, 8, 8))})
        t.report("nomat", t.translate(1))

        def fog(with_grid):
            mat = bpy.data.materials.new("Fog")
            nt = mat.node_tree
            nt.nodes.clear()
            sc = nt.nodes.new("ShaderNodeVolumeScatter")
            sc.inputs["Density"].default_value = 0.25
            em = nt.nodes.new("ShaderNodeEmission")
            em.inputs["Strength"].default_value = 2.0
            add = nt.nodes.new("ShaderNodeAddShader")
            out = nt.nodes.new("ShaderNodeOutputMaterial")
            nt.links.new(sc.outputs[0], add.inputs[0])
            nt.links.new(em.outputs[0], add.inputs[1])
            if with_grid:
                pv = nt.nodes.new("ShaderNodeVolumePrincipled")
                add2 = nt.nodes.new("ShaderNodeAddShader")
                nt.links.new(add.outputs[0], add2.inputs[0])
                nt.links.new(pv.outputs[0], add2.inputs[1])
                add = add2
            nt.links.new(add.outputs[0], out.inputs["Volume"])
            return mat

        ob.data.materials.append(fog(False))
        t.report("uniform_only", t.translate(1))
        ob.data.materials.clear()
        ob.data.materials.append(fog(True))
        t.report("uniform_and_grid", t.translate(1))
        ob.data.materials.clear()
        ob.data.materials.append(t.volume_material("Odd", attribute="smoke"))
        t.report("unknown_attr", t.translate(1))
    """
    r = run(body, tmp_path)
    assert r["nomat"]["media"] == []
    warned(r["nomat"], "'Smoke'", "no material")
    # a uniform scatter and emission alone: no grid is read, so nothing (as in Cycles)
    assert r["uniform_only"]["media"] == []
    warned(r["uniform_only"], "'Smoke'", "reads no smoke grid")
    # beside a density shader they fill the density's non-zero cells
    media = {m["name"]: m for m in r["uniform_and_grid"]["media"]}
    assert set(media) == {"Smoke:density", "Smoke:uniform"}
    dens, box = media["Smoke:density"], media["Smoke:uniform"]
    assert box["source"] == "FLUID" and box["shape"] == dens["shape"] and box["max"] == 1.0
    np.testing.assert_allclose(box["origin_world"], dens["origin_world"])
    np.testing.assert_allclose(box["sigma_s"], [0.2] * 3, rtol=1e-6)  # 0.8 x 0.25
    np.testing.assert_allclose(box["emission"], [2.0] * 3, rtol=1e-6)
    np.testing.assert_allclose(dens["sigma_s"], [0.5] * 3, rtol=1e-6)  # default Principled
    warned(r["uniform_and_grid"], "'Smoke'", "uniform density", "'Smoke:density'")
    # a Density Attribute naming no smoke grid: a uniform density, with no grid read: nothing
    assert r["unknown_attr"]["media"] == []
    warned(r["unknown_attr"], "'Smoke'", "no scalar grid 'smoke'")


def test_unbaked_domain_and_the_live_grids_are_reported(tmp_path):
    body = """
        ob = t.domain(CACHE, t.volume_material(), cache_type="REPLAY")
        from mpp_render.blender.translate import fluid
        dse = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).modifiers["Fluid"].domain_settings
        live = fluid.live_grids(dse)
        print("RESULT", json.dumps({"tag": "live", "none": live is None,
                                    "res": list(dse.domain_resolution),
                                    "n": len(dse.density_grid)}))
        t.report("unbaked", t.translate(1))
    """
    r = run(body, tmp_path)
    # the live grids exist with the domain's size but hold nothing here (no simulation)
    assert r["live"]["none"] and r["live"]["res"] == list(RES) and r["live"]["n"] == int(np.prod(RES))
    assert r["unbaked"]["media"] == []
    warned(r["unbaked"], "'Smoke'", "no simulation data at frame 1", "fluid_data_0001.vdb")


def test_a_slow_reader_is_stopped_and_reported(tmp_path):
    body = """
        ob = t.domain(CACHE, t.volume_material())
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": t.plume(t.RES, (16, 8, 8))})
        t.report("f1", t.translate(1))
    """
    r = run(body, tmp_path, env={"MPP_FLUID_READ_TIMEOUT_S": "0.001"})
    assert r["f1"]["media"] == []
    warned(r["f1"], "'Smoke'", "fluid_data_0001.vdb", "took longer than", "skipped")


RENDER_SCENE = """
    from mpp_render.blender import engine, frame, properties
    properties.register(); engine.register()
    sc = bpy.context.scene
    sc.world = bpy.data.worlds.new("World")
    sc.world.color = (0, 0, 0)
    ob = t.domain(CACHE, t.volume_material(density=40.0))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sc.collection.objects.link(sun)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 2.0
    cam.location = (1.0, -6.0, 3.0)       # looking along +Y at the domain's middle
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.render.engine = "MPP_RENDER"
    sc.render.resolution_x, sc.render.resolution_y = 64, 32
    sc.render.resolution_percentage = 100
    sc.mpp.samples = 1
    sc.mpp.multiple = False
"""


def test_render_shows_the_smoke_where_the_grid_puts_it(tmp_path):
    body = RENDER_SCENE + """
    t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": t.plume(t.RES, (24, 8, 8), 3.0)})
    open(CACHE + "/data/fluid_data_0002.vdb", "wb").write(b"not a vdb file at all" * 10)
    for f in (1, 2):
        sc.frame_set(f)
        out = frame.render_mpp().output
        T = out.passes["Transmittance"].mean(axis=2)
        print("RESULT", json.dumps({"tag": f"f{f}", "T_cols": T.mean(axis=0).tolist(),
                                    "T_rows": T.mean(axis=1).tolist(),
                                    "single": float(out.passes["Volume Single"].sum()),
                                    "warnings": out.warnings, "media": []}))
    """
    r = run(body, tmp_path)
    cols = np.array(r["f1"]["T_cols"])
    # the frame spans x 0..2 m in 64 columns; the puff sits at x = 0.5 + 24 x 0.0625 = 1.53 m
    darkest = int(np.argmin(cols))
    x = (darkest + 0.5) / 64 * 2.0
    assert abs(x - cell_centre((24, 8, 8))[0]) < 0.07, x
    assert cols[darkest] < 0.5 and np.all(cols[:16] > 0.999)  # the left part is clear
    rows = np.array(r["f1"]["T_rows"])
    assert abs(int(np.argmin(rows)) - 15.5) <= 1.5  # vertically in the middle (z = 3.0625)
    assert r["f1"]["single"] > 0
    # a corrupt frame: reported by name, the frame renders empty instead of failing
    assert np.all(np.array(r["f2"]["T_cols"]) == 1.0)
    warned(r["f2"], "'Smoke'", "fluid_data_0002.vdb")


# -- fire: emission driven by the flame / temperature / heat grids -------------------------------

# The fire puff: smoke over the middle of the domain, flame (peak 0.2) in its upper right
# corner.  With the domain's default Ignition 1.5 and Maximum 3.0 the 'temperature' grid is
# 1.5 + 1.5 flame where flame > 0.01, so Temperature 1000 K gives 1515 .. 1800 K: red-orange.
FLAME_CELL = (26, 8, 11)
FLAME_PEAK = 0.2
T_PEAK = 1000.0 * (1.5 + 1.5 * FLAME_PEAK)

FIRE_SCENE = RENDER_SCENE.replace("t.volume_material(density=40.0)", "MATERIAL") + """
    sc.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    DENS = t.plume(t.RES, (16, 8, 8), 4.0)
    FLAME = t.FLAME_PEAK * t.plume(t.RES, t.FLAME_CELL, 2.0)

    def passes():
        out = frame.render_mpp().output
        return {k: out.passes[k][..., :3].tolist() for k in ("Combined", "Volume Single",
                                                            "Emission")}
"""


def pixel(point):
    """(row, column) of the 64 x 32 RENDER_SCENE image that sees the world ``point`` (rows
    from the top; the frame spans x 0..2 m and z 2.5..3.5 m)."""
    return int((3.5 - point[2]) / 1.0 * 32), int(point[0] / 2.0 * 64)


def test_fire_glows_with_the_blackbody_of_its_flame_grid(tmp_path):
    from mpp_render import blackbody
    body = FIRE_SCENE.replace("MATERIAL", "t.fire_material()") + """
    t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": DENS, "flame": FLAME})
    desc = t.translate(1)
    (m,) = desc.media
    print("RESULT", json.dumps({"tag": "media", "media": [t.medium_record(m)],
                                "warnings": desc.warnings,
                                "hot": t.emission_at(m, t.cell_centre(t.FLAME_CELL)),
                                "cold": t.emission_at(m, t.cell_centre((10, 8, 8))),
                                "density_cold": float(DENS[10, 8, 8])}))
    sc.frame_set(1)
    print("RESULT", json.dumps(dict(tag="fire", warnings=[], media=[], **passes())))
    ob.data.materials.clear()
    ob.data.materials.append(t.volume_material("Smoke only", density=10.0))
    print("RESULT", json.dumps(dict(tag="smoke", warnings=[], media=[], **passes())))
    """
    r = run(body, tmp_path)
    m = only(r["media"])
    assert m["source"] == "FLUID" and not [w for w in r["media"]["warnings"] if "Smoke" in w]
    # per voxel: the blackbody at Temperature x temperature, the constant part (1000 K) gone
    np.testing.assert_allclose(r["media"]["hot"], blackbody.emission(T_PEAK, 1.0), rtol=1e-5)
    assert r["media"]["hot"][0] > r["media"]["hot"][1] > r["media"]["hot"][2] >= 0.0
    assert r["media"]["cold"] == [0.0, 0.0, 0.0] and r["media"]["density_cold"] > 0.1
    assert m["emission"] == [0.0, 0.0, 0.0]
    em, single, comb = (np.array(r["fire"][k]) for k in ("Emission", "Volume Single", "Combined"))
    # the glow sits where the flame is: the centre of its bright part (over half its peak)
    # sees the flame's peak cell (its single brightest pixel is one of a flat top: the
    # pixels' own samples pick it)
    red = em[..., 0]
    rr, cc = np.nonzero(red >= 0.5 * red.max())
    wt = red[rr, cc]
    centre = (float(np.average(rr, weights=wt)), float(np.average(cc, weights=wt)))
    want = pixel(cell_centre(FLAME_CELL))
    assert abs(centre[0] - want[0]) <= 1.0 and abs(centre[1] - want[1]) <= 1.0, (centre, want)
    row, col = np.unravel_index(int(np.argmax(red)), red.shape)
    hot = em[row, col]
    assert hot[0] > hot[1] > hot[2] >= 0.0 and hot[0] > 0.02      # red-orange
    # no emission where there is no flame (the left half: smoke, flame 0)
    assert np.all(em[:, :32] == 0.0) and single[:, :32].max() > 0.01
    # Combined = scattered light + emission (black world, single scattering only)
    np.testing.assert_allclose(comb, single + em, rtol=1e-5, atol=1e-7)
    assert single.max() > 0.01 and em.max() > 0.1 * single.max()
    # the same smoke with a material without blackbody emits nothing
    smoke = {k: np.array(r["smoke"][k]) for k in ("Emission", "Combined", "Volume Single")}
    assert np.all(smoke["Emission"] == 0.0) and smoke["Volume Single"].max() > 0.01
    np.testing.assert_allclose(smoke["Combined"], smoke["Volume Single"], rtol=1e-5, atol=1e-7)


def test_fire_domain_glows_as_a_volume_object_with_the_same_grids(tmp_path):
    """One implementation serves both: the domain's 'temperature' (from flame) and a Volume
    object holding the same density and temperature grids on the same cells, with the same
    shader, give the same per-voxel emission and the same Emission pass."""
    body = FIRE_SCENE.replace("MATERIAL", "t.fire_material()") + """
    t.write_frame(CACHE + "/data/fluid_data_0001.vdb", {"density": DENS, "flame": FLAME})
    temp = np.where(FLAME > 0.01, 1.5 + 1.5 * FLAME, 0.0).astype(np.float32)
    points = [t.cell_centre(c).tolist() for c in (t.FLAME_CELL, (24, 7, 10), (27, 9, 13),
                                                   (10, 8, 8))]
    sc.frame_set(1)
    records = {}
    for kind in ("fluid", "vdb"):
        if kind == "vdb":
            bpy.data.objects.remove(ob)
            t.write_frame(CACHE + "/fire.vdb", {"density": DENS, "temperature": temp})
            vol = bpy.data.volumes.new("FireVDB")
            vol.filepath = CACHE + "/fire.vdb"
            vol.materials.append(t.fire_material("FireVDB"))
            vob = bpy.data.objects.new("FireVDB", vol)
            vob.location = t.LO + 0.5 * t.CELL     # voxel (0,0,0) at the domain's first cell
            sc.collection.objects.link(vob)
        desc = t.translate(1)
        print("RESULT", json.dumps(dict(tag=kind, warnings=desc.warnings, media=[],
                                        at=[t.emission_at(desc.media[0], p) for p in points],
                                        n=len(desc.media), **passes())))
    """
    r = run(body, tmp_path)
    fl, vd = r["fluid"], r["vdb"]
    assert fl["n"] == vd["n"] == 1, (fl["warnings"], vd["warnings"])
    np.testing.assert_allclose(fl["at"], vd["at"], rtol=1e-5, atol=1e-9)
    assert max(fl["at"][0]) > 0.1 and fl["at"][3] == [0.0, 0.0, 0.0]
    for name in ("Emission", "Combined"):
        a, b = np.array(fl[name]), np.array(vd[name])
        assert a.max() > 0.05, name
        np.testing.assert_allclose(a.sum(axis=(0, 1)), b.sum(axis=(0, 1)), rtol=0.01)
        assert np.abs(a - b).max() < 0.02 * a.max(), name


def test_fire_strength_attributes_heat_noise_lattice_and_missing_grids(tmp_path):
    from mpp_render import blackbody
    body = """
        ob = t.domain(CACHE, t.fire_material(), noise=2)
        res2 = tuple(2 * n for n in t.RES)
        heat = 1.6 * t.plume(t.RES, (12, 8, 8))                 # 'heat' = 0.8 at its peak
        t.write_frame(CACHE + "/data/fluid_data_0001.vdb",
                      {"density": t.plume(t.RES, (16, 8, 8), 4.0), "temperature": heat})
        t.write_frame(CACHE + "/noise/fluid_noise_0001.vdb",
                      {"density_noise": t.plume(res2, (32, 16, 16), 8.0),
                       "flame_noise": 0.5 * t.plume(res2, (41, 16, 16), 4.0)}, voxel=t.CELL / 2)
        # smoke only at frame 2: no flame grid in the files
        t.write_frame(CACHE + "/data/fluid_data_0002.vdb", {"density": t.plume(t.RES, (16, 8, 8))})
        t.write_frame(CACHE + "/noise/fluid_noise_0002.vdb",
                      {"density_noise": t.plume(res2, (32, 16, 16), 8.0)}, voxel=t.CELL / 2)
        hi = lambda ijk: (t.LO + (np.asarray(ijk) + 0.5) * t.CELL / 2).tolist()
        probes = {"flame_peak": hi((41, 16, 16)), "heat_peak": hi((24, 16, 16)),
                  "far": hi((4, 16, 16))}

        def record(tag, frame=1):
            desc = t.translate(frame)
            print("RESULT", json.dumps({
                "tag": tag, "media": [t.medium_record(m) for m in desc.media],
                "warnings": desc.warnings,
                "at": {k: [t.emission_at(m, p) for m in desc.media] for k, p in probes.items()},
                "grid_cells": [None if m.emission_grid is None else
                               np.linalg.norm(m.index_to_world[:3, :3], axis=0).tolist()
                               for m in desc.media]}))

        def use(mat):
            ob.data.materials.clear()
            ob.data.materials.append(mat)

        record("temperature")                      # the fire shader, flame from the noise file
        use(t.fire_material("Heat", temperature_attribute="heat"))
        record("heat")
        use(t.fire_material("Strength", blackbody=0.0, strength_attribute="flame"))
        record("strength")
        use(t.emission_material("flame"))
        record("emission_shader")
        use(t.fire_material("Nothing", blackbody=0.0, strength_attribute="smoke"))
        record("no_such_grid")
        use(t.fire_material("Fire again"))
        record("smoke_only", frame=2)
        # fire without smoke at frame 3: flame only, the density grid empty
        t.write_frame(CACHE + "/data/fluid_data_0003.vdb", {"temperature": heat})
        t.write_frame(CACHE + "/noise/fluid_noise_0003.vdb",
                      {"flame_noise": 0.5 * t.plume(res2, (41, 16, 16), 4.0)}, voxel=t.CELL / 2)
        record("fire_only", frame=3)
        # a mesh volume has no grids: the strength attribute reads 0 there too (warned)
        bpy.data.objects.remove(ob)
        bpy.ops.mesh.primitive_cube_add(location=(5.0, 0.0, 0.0))
        bpy.context.object.data.materials.append(
            t.fire_material("MeshGlow", blackbody=0.0, strength_attribute="flame"))
        record("mesh")
    """
    r = run(body, tmp_path)
    ign, top = 1.5, 3.0
    # 'temperature' = ignition + flame (max - ignition) on the noise lattice, x 1000 K
    te = only(r["temperature"])
    np.testing.assert_allclose(te["cell"], [CELL / 2] * 3, rtol=1e-12)
    t_peak = 1000.0 * (ign + 0.5 * (top - ign))
    np.testing.assert_allclose(r["temperature"]["at"]["flame_peak"][0],
                               blackbody.emission(t_peak, 1.0), rtol=1e-5)
    assert r["temperature"]["at"]["far"][0] == [0.0, 0.0, 0.0]
    # 'heat' stays low-resolution and is resampled onto the noise lattice of the density: the
    # noise cell beside the heat's peak lies a quarter cell off each axis, so its value is the
    # Gaussian's trilinear mix (0.75 + 0.25 e^(-1/8))^3 x 0.8
    he = r["heat"]["at"]["heat_peak"][0]
    heat_there = 0.8 * (0.75 + 0.25 * np.exp(-1 / 8)) ** 3
    np.testing.assert_allclose(he, blackbody.emission(1000.0 * heat_there, 1.0), rtol=1e-4)
    assert r["heat"]["grid_cells"] == [[CELL / 2] * 3]
    # an Attribute node reading 'flame' into Emission Strength: Emission Color x flame
    np.testing.assert_allclose(r["strength"]["at"]["flame_peak"][0],
                               0.5 * np.array([1.0, 0.5, 0.25]), rtol=1e-5)
    assert only(r["strength"])["emission"] == [0.0, 0.0, 0.0]
    # an Emission shader alone whose Strength reads 'flame': it glows over the flame's cells
    es = only(r["emission_shader"])
    assert es["name"] == "Smoke:uniform" and es["sigma_s"] == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(r["emission_shader"]["at"]["flame_peak"][0],
                               0.5 * np.array([1.0, 0.5, 0.25]), rtol=1e-5)
    # an attribute no domain has: Cycles reads 0, so no emission (warned)
    assert r["no_such_grid"]["at"]["flame_peak"] == [None]
    assert only(r["no_such_grid"])["emission"] == [0.0, 0.0, 0.0]
    warned(r["no_such_grid"], "'Smoke'", "'smoke'", "'Emission Strength'", "emission is 0")
    # no flame at this frame: the domain's temperature is 0, no glow -- not the constant
    # Temperature a Volume object without the grid would get
    so = only(r["smoke_only"])
    assert r["smoke_only"]["at"]["flame_peak"] == [None] and so["emission"] == [0.0, 0.0, 0.0]
    warned(r["smoke_only"], "'Smoke'", "'temperature'", "holds no data")
    # fire without smoke glows on a zero density (Cycles emits wherever the shader runs)
    fo = only(r["fire_only"])
    assert fo["max"] == 0.0
    np.testing.assert_allclose(r["fire_only"]["at"]["flame_peak"][0],
                               blackbody.emission(t_peak, 1.0), rtol=1e-5)
    warned(r["fire_only"], "'Smoke'", "'density'", "holds no data")
    mesh = only(r["mesh"])
    assert mesh["source"] == "MESH" and mesh["emission"] == [0.0, 0.0, 0.0]
    warned(r["mesh"], "'MeshGlow'", "'flame'", "'Emission Strength'", "emission is 0")
