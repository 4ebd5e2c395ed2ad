"""The import direction of docs/structure.md, read from the source: a module of the numeric
core imports only modules of its own layer or below (glue -> render -> precompute / march ->
kernels -> physics and media -> scene), and nothing under mpp_render/ outside
mpp_render/blender/ imports bpy."""
import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1] / "mpp_render"

# top to bottom; a module not named here is a failure (name it in docs/structure.md first)
LAYERS = [
    {"cli", "__main__", "package", "blender", "viewport"},              # entry points, glue
    {"render", "tiles", "pixelsamples", "pilot", "cache", "bounce", "budget", "metrics",
     "exr"},                                                            # the frame; I/O
    {"precompute", "march", "firstflight", "pyramid", "blasthreads",
     "surfaces", "surfacecache"},                                                     # the two stages
    {"kernels", "kernels_np", "_kernels", "paths"},                     # C kernels, numpy twins
    {"lights", "gathers", "principled", "worldfog", "media", "phase", "mpp", "walk",
     "lightrecord",
     "camera", "blackbody", "passes", "textures", "rng"},                                # physics, media, model
    {"scene", "cancel", "parallel"},                                    # the description; Esc
]


def layer_of(module: str) -> int:
    top = module.split(".")[0]
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    raise AssertionError(f"mpp_render.{module} is in no layer of docs/structure.md")


def core_modules():
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if not parts:
            continue
        yield ".".join(parts), path


def imports_of(module: str, path: pathlib.Path):
    """(mpp_render-relative module names imported, other top-level names imported)."""
    tree = ast.parse(path.read_text())
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    inner, outer = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                target = base + (node.module.split(".") if node.module else [])
                if target:
                    inner.add(".".join(target))
                else:  # from . import a, b
                    inner.update(a.name for a in node.names)
            elif node.module:
                (inner if node.module.startswith("mpp_render.") else outer).add(
                    node.module.replace("mpp_render.", "", 1) if node.module.startswith("mpp_render.")
                    else node.module.split(".")[0])
        elif isinstance(node, ast.Import):
            for a in node.names:
                outer.add(a.name.split(".")[0])
    return inner, outer


def test_every_core_module_imports_downwards():
    wrong = []
    for module, path in core_modules():
        if module.split(".")[0] == "blender":
            continue
        mine = layer_of(module)
        inner, _ = imports_of(module, path)
        for target in inner:
            if layer_of(target) < mine:
                wrong.append(f"{module} (layer {mine}) imports {target} (layer {layer_of(target)})")
    assert not wrong, "\n".join(wrong)


def test_no_bpy_outside_the_glue():
    found = [module for module, path in core_modules()
             if module.split(".")[0] != "blender" and "bpy" in imports_of(module, path)[1]]
    assert not found, found


def test_the_check_sees_a_wrong_import(tmp_path):
    """The checker itself: a module of the kernels' layer importing render is caught."""
    bad = tmp_path / "kernels.py"
    bad.write_text("from .render import render\nimport bpy\n")
    inner, outer = imports_of("kernels", bad)
    assert inner == {"render"} and "bpy" in outer
    assert layer_of("render") < layer_of("kernels")
