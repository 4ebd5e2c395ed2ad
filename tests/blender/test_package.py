"""``python -m mpp_render package``: the extension zip carries the C kernels as a wheel, and
Blender installs it, renders on the compiled kernels from that wheel and removes it again.
(The plain zip of the checkout is tested in test_engine.py.)"""
import json
import math
import os
import subprocess
import sys
import tomllib
import zipfile

import pytest

bpy = pytest.importorskip("bpy")

from conftest import REPO
from mpp_render import package

WHEEL = f"mpp_render_kernels-0.1.0-{package.wheel_tag()}.whl"

INSTALL_SCRIPT = r"""
import json, math, os, sys
import bpy, addon_utils

out = {}
bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default",
                                         enable_on_install=True)
repos = bpy.context.preferences.extensions.repos
repo_index = [r.module for r in repos].index("user_default")
out["ext_dir"] = os.path.join(repos[repo_index].directory, "mpp_render")
pkg = "bl_ext.user_default.mpp_render"
assert pkg in sys.modules and "mpp_render" not in sys.modules  # not the checkout

# A 16x12 scene: a 2 m cube of Principled Volume under a sun, seen from 8 m (the startup
# file's objects removed; a factory reset would disable the extension).
sc = bpy.context.scene
for ob in list(bpy.data.objects):
    bpy.data.objects.remove(ob)
mat = bpy.data.materials.new("Vol")
nt = mat.node_tree
nt.nodes.clear()
pv = nt.nodes.new("ShaderNodeVolumePrincipled")
pv.inputs["Density"].default_value = 2.0
nt.links.new(pv.outputs["Volume"], nt.nodes.new("ShaderNodeOutputMaterial").inputs["Volume"])
mesh = bpy.data.meshes.new("Cube")
mesh.from_pydata([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], [],
                 [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)])
mesh.materials.append(mat)
sc.collection.objects.link(bpy.data.objects.new("Cube", mesh))
sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
sun.data.energy = 3.0
sc.collection.objects.link(sun)
cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
cam.location = (0.0, -8.0, 0.0)
cam.rotation_euler = (math.pi / 2, 0.0, 0.0)
sc.collection.objects.link(cam)
sc.camera = cam
sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 16, 12, 100
sc.render.engine = "MPP_RENDER"
sc.mpp.samples = 1
sc.mpp.voxel_resolution = 8
frame = sys.modules[pkg + ".mpp_render.blender.frame"]
with frame.collect() as frames:
    bpy.ops.render.render()

kernels = sys.modules[pkg + ".mpp_render.kernels"]
last = frames[-1] if frames else None
out["backend"] = kernels.backend()
out["kernels_module"] = kernels._c.__name__ if kernels._c is not None else None
out["kernels_file"] = getattr(kernels._c, "__file__", None)
out["rendered"] = last is not None
out["min_transmittance"] = float(last.output.passes["Transmittance"].min()) if last else None
# The operators package, imported relatively inside the installed extension.
assert bpy.ops.mpp.compare_with_cycles(samples=1) == {'FINISHED'}
out["compare_rel_rmse"] = json.loads(sc["mpp_last_compare"])["rel_rmse"]
assert bpy.ops.mpp.clear_cache() == {'FINISHED'}
out["cleared"] = len(sys.modules[pkg + ".mpp_render.cache"].CACHE) == 0

bpy.ops.extensions.package_uninstall(repo_index=repo_index, pkg_id="mpp_render")
out["ext_dir_after"] = os.path.isdir(out["ext_dir"])
out["kernels_file_after"] = os.path.exists(out["kernels_file"] or "")
print("RESULT " + json.dumps(out))
"""


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The zip built by the command line (once for this module) and its JSON record."""
    out = tmp_path_factory.mktemp("pkg")
    env = dict(os.environ)
    env.pop("MPP_SANITIZE", None)
    p = subprocess.run([sys.executable, "-m", "mpp_render", "package", "--output-dir", str(out)],
                       cwd=str(REPO), env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    rec = json.loads(p.stdout.strip().splitlines()[-1])
    return rec


def test_zip_validates_and_carries_the_kernels_wheel(built, tmp_path):
    zip_path = built["zip"]
    assert os.path.isfile(zip_path) and zip_path.endswith("mpp_render-0.1.0.zip")
    assert built["wheel"] == f"wheels/{WHEEL}"
    cli = package.blender_ext_cli()
    p = subprocess.run([sys.executable, str(cli), "validate", zip_path],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stdout + p.stderr

    with zipfile.ZipFile(zip_path) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
        zf.extract(built["wheel"], tmp_path)
    assert built["wheel"] in names
    assert manifest["wheels"] == [f"./wheels/{WHEEL}"]
    assert not [n for n in names if n.endswith((".so", ".pyd"))]  # the kernels only as a wheel
    assert "operators/__init__.py" in names

    # A well-formed wheel for this interpreter: pip accepts its tags and RECORD.
    target = tmp_path / "site"
    p = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                        "--disable-pip-version-check", "--target", str(target),
                        str(tmp_path / built["wheel"])], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stdout + p.stderr
    assert sorted(os.listdir(target / "mpp_render_kernels"))[0] == "__init__.py"


def test_packaging_leaves_the_checkout_alone(built):
    """No build products in the repository (the wheel and the build live in a temp dir)."""
    assert not (REPO / "wheels").exists()
    assert not list(REPO.glob("*.egg-info"))
    with open(REPO / "blender_manifest.toml", "rb") as fh:
        assert "wheels" not in tomllib.load(fh)


def test_installed_zip_renders_on_the_wheels_kernels_and_uninstalls(built, tmp_path):
    user = tmp_path / "user"
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user))
    env.pop("PYTHONPATH", None)
    env.pop("MPP_KERNELS", None)
    p = subprocess.run([sys.executable, "-c", INSTALL_SCRIPT, built["zip"]], cwd=str(tmp_path),
                       env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-3000:]
    (line,) = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
    out = json.loads(line[len("RESULT "):])
    assert out["rendered"] and out["min_transmittance"] < 0.9
    assert out["backend"] == "c"
    assert out["kernels_module"] == "mpp_render_kernels._kernels"  # from the wheel
    assert out["kernels_file"].startswith(str(user))
    assert math.isfinite(out["compare_rel_rmse"]) and out["cleared"]
    assert not out["ext_dir_after"] and not os.path.exists(out["ext_dir"])
    assert not out["kernels_file_after"]  # uninstalling removed the wheel's files too
