"""The artist's tools of MPP Render: *Compare with Cycles* and *Clear MPP Caches*.

Imported by the extension's root ``__init__`` as ``.operators``; nothing here is needed to
render.  The work is done by plain functions (``compare_with_cycles``, ``clear_caches`` and
their helpers) that the tests call directly; the operator classes only forward to them and
report.  The tools are found in *Properties -> Render -> MPP Tools* and in the *Render* menu
of the top bar (both only while MPP is the render engine).

Installed, this package is ``bl_ext.<repository>.mpp_render.operators`` and the renderer is
the sibling package ``..mpp_render``; in a checkout (tests) both are top-level packages.
"""
import gc
import json
import math
import os
import sys
import tempfile

import bpy
import numpy as np

if __package__ and "." in __package__:  # installed: a subpackage of the extension
    from ..mpp_render import cache, metrics
    from ..mpp_render.blender import batch
else:  # a checkout: ``operators`` and ``mpp_render`` are both top-level
    from mpp_render import cache, metrics
    from mpp_render.blender import batch

ENGINE = "MPP_RENDER"
DIFF_IMAGE = "MPP Difference"
COMPARE_PROP = "mpp_last_compare"
DEFAULT_CYCLES_SAMPLES = 64
MB = 1 << 20  # as in budget.py: the MB of the memory settings

# Image settings that render_current changes to save Cycles' render as a multilayer EXR, in
# the order they must be set back (the media type resets the format, the format the rest).
IMAGE_SETTING_KEYS = ("media_type", "file_format", "color_mode", "color_depth", "exr_codec")


# --- saving and restoring scene settings -------------------------------------------------

def _plain(value):
    """A comparable copy of an RNA property value (arrays become tuples, flag sets sets)."""
    if isinstance(value, (str, bytes, int, float, bool)) or value is None:
        return value
    if isinstance(value, set):
        return set(value)
    try:
        return tuple(value)
    except TypeError:
        return value


def snapshot(rna, keys=None) -> dict:
    """The values of ``rna``'s writable plain properties (or of ``keys``), to ``restore``."""
    if keys is None:
        keys = [p.identifier for p in rna.bl_rna.properties
                if p.identifier != "rna_type" and not p.is_readonly
                and p.type not in {"POINTER", "COLLECTION"}]
    return {k: _plain(getattr(rna, k)) for k in keys if hasattr(rna, k)}


def restore(rna, saved: dict) -> None:
    """Set back every property of ``saved`` that differs now (in ``saved``'s order).  A value
    Blender refuses (an enum item that is no longer valid) is left as it is."""
    for key, value in saved.items():
        if _plain(getattr(rna, key)) == value:
            continue
        try:
            setattr(rna, key, value)
        except (TypeError, ValueError, AttributeError):
            pass


# --- compare with Cycles -----------------------------------------------------------------

def difference_map(ours: np.ndarray, ref: np.ndarray):
    """A red/blue heat map of ``ours - ref`` (both (H, W, >=3) linear RGB, row 0 at the top).

    The signed difference of the channel means is divided by the mean of the reference, so a
    pixel's value is its error relative to the image's mean brightness (the normalisation of
    ``rel_rmse``): red where MPP is brighter than Cycles, blue where it is darker; 1.0 is a
    difference as large as the mean brightness (values above 1 are kept: a float image).
    Returns the (H, W, 4) float32 RGBA map (row 0 at the top) and the divisor."""
    d = np.asarray(ours, np.float64)[..., :3].mean(axis=2) - np.asarray(ref, np.float64)[..., :3].mean(axis=2)
    d = np.nan_to_num(d, nan=0.0, posinf=0.0, neginf=0.0)
    scale = float(np.mean(np.asarray(ref, np.float64)[..., :3]))
    if not (math.isfinite(scale) and scale > 0.0):  # a black reference: fall back to the largest error
        scale = float(np.max(np.abs(d))) or 1.0
    rgba = np.zeros(d.shape + (4,), np.float32)
    rgba[..., 0] = np.maximum(d, 0.0) / scale
    rgba[..., 2] = np.maximum(-d, 0.0) / scale
    rgba[..., 3] = 1.0
    return rgba, scale


def store_difference_image(rgba: np.ndarray, name: str = DIFF_IMAGE):
    """Write ``rgba`` ((H, W, 4), row 0 at the top) into the float image ``name`` (created, or
    resized in place so an Image Editor showing it keeps showing it)."""
    h, w = rgba.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and not img.is_float:
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    elif tuple(img.size) != (w, h):
        img.scale(w, h)
    img.pixels.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())  # bottom row first
    img.update()
    return img


def _finite_or_none(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def compare_with_cycles(scene, samples: int = DEFAULT_CYCLES_SAMPLES, seed: int = 0) -> dict:
    """Render ``scene``'s current frame (the context's scene, active view layer) with MPP and
    then with Cycles at ``samples`` spp and the reference settings (``batch.set_cycles_reference``,
    volume bounces following MPP's *Multiple Scattering*), and score MPP's Combined pass
    against the Cycles render with ``metrics.compare`` (that single run is the reference, so
    the numbers include Cycles' own noise; ``floor`` is None).

    Stores the difference map in ``bpy.data.images["MPP Difference"]`` and the returned record
    as JSON in ``scene["mpp_last_compare"]``.  The scene's engine, Cycles settings and output
    image settings are restored afterwards.  Stops after MPP's render when that render was
    cancelled (``cancelled`` True, no metrics).  Returns the record; ``compare_renders`` does
    the same and also hands back both renders' records (with their passes)."""
    return compare_renders(scene, samples, seed)[0]


def compare_renders(scene, samples: int = DEFAULT_CYCLES_SAMPLES, seed: int = 0):
    """``compare_with_cycles``'s work: returns ``(record, ours, ref)`` where ``ours`` and
    ``ref`` are ``batch.render_current``'s records of the MPP and the Cycles render (``ref``
    None when MPP's was cancelled); ``ours["_frame"]`` is MPP's ``frame.FrameRecord``."""
    if scene != bpy.context.scene:
        raise ValueError("compare_with_cycles renders the context's scene only")
    if not hasattr(scene, "cycles"):
        raise RuntimeError("Cycles is not available (the Cycles add-on is disabled)")
    samples = int(samples)
    saved_engine = scene.render.engine
    saved_cycles = snapshot(scene.cycles)
    saved_image = snapshot(scene.render.image_settings, IMAGE_SETTING_KEYS)
    ref = None
    with tempfile.TemporaryDirectory(prefix="mpp_compare_") as tmp:
        try:
            scene.render.engine = ENGINE
            ours = batch.render_current(scene, os.path.join(tmp, "mpp.exr"))
            if not ours["cancelled"]:
                batch.set_cycles_reference(scene, samples, multiple=scene.mpp.multiple, seed=seed)
                ref = batch.render_current(scene, os.path.join(tmp, "cycles.exr"))
        finally:
            scene.render.engine = saved_engine
            restore(scene.cycles, saved_cycles)
            restore(scene.render.image_settings, saved_image)

    rec = {
        "frame": scene.frame_current,
        "resolution": ours["resolution"],
        "mpp_samples": int(scene.mpp.samples),
        "multiple": bool(scene.mpp.multiple),
        "cycles_samples": samples,
        "mpp_seconds": ours["render"],
        "cancelled": bool(ours["cancelled"]),
        "warnings": ours["warnings"],
    }
    if ref is not None:
        x = ours["_passes"]["Combined"]
        r = ref["_passes"]["Combined"]
        m = metrics.compare(x, [r])
        rgba, scale = difference_map(x, r)
        store_difference_image(rgba)
        rec.update({k: m[k] for k in ("rel_rmse", "bias", "rel_rmse_4", "failed")})
        if m.get("reason"):
            rec["reason"] = m["reason"]
        rec["cycles_seconds"] = ref["render"]
        rec["speedup"] = ref["render"] / ours["render"] if ours["render"] > 0 else None
        rec["difference_scale"] = scale
        rec["difference_image"] = DIFF_IMAGE
    rec = {k: _finite_or_none(v) for k, v in rec.items()}
    scene[COMPARE_PROP] = json.dumps(rec)
    return rec, ours, ref


def compare_summary(rec: dict) -> str:
    """One line for the status bar."""
    if rec.get("cancelled"):
        return "MPP: render cancelled; Cycles was not run"
    if rec.get("failed"):
        return f"MPP: our render has non-finite pixels ({rec.get('reason', '')})"

    def num(key, fmt):
        v = rec.get(key)
        return "n/a" if v is None else format(v, fmt)

    return (f"MPP vs Cycles {rec['cycles_samples']} spp: rel_rmse {num('rel_rmse', '.4f')}, "
            f"rel_rmse_4 {num('rel_rmse_4', '.4f')}, bias {num('bias', '+.4f')}; "
            f"MPP {num('mpp_seconds', '.2f')} s, Cycles {num('cycles_seconds', '.2f')} s "
            f"(difference in image '{DIFF_IMAGE}')")


def last_compare(scene):
    """The record of the last comparison stored in ``scene``, or None."""
    text = scene.get(COMPARE_PROP)
    if not text:
        return None
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return None


# --- caches ------------------------------------------------------------------------------

def _renderer_package() -> str:
    """The renderer's package name: ``mpp_render`` in a checkout, longer when installed."""
    return batch.__name__.rsplit(".blender.batch", 1)[0]


def cached_functions():
    """The ``functools`` caches (``cache_clear``/``cache_info``) defined at module level in
    the renderer's loaded modules."""
    root = _renderer_package()
    seen = set()
    for name, mod in list(sys.modules.items()):
        if mod is None or not (name == root or name.startswith(root + ".")):
            continue
        for obj in list(vars(mod).values()):
            if (callable(getattr(obj, "cache_clear", None)) and hasattr(obj, "cache_info")
                    and getattr(obj, "__module__", None) == name and id(obj) not in seen):
                seen.add(id(obj))
                yield obj


def clear_caches() -> dict:
    """Drop what the renderer keeps between renders: its store of reusable work
    (``mpp_render.cache``: precompute fields, light pyramids, voxelised meshes, grids read
    from files) and its module-level function caches.  The engine keeps no frame (each frame's
    record goes back to whoever asked for it), and Blender's own Render Result is left to
    Blender.  Returns ``{"cache_mb", "functions", "entries"}``: the MB (2^20 bytes) of arrays
    the store held, the function caches cleared and the entries they held."""
    stored = cache.clear()
    functions = entries = 0
    for fn in cached_functions():
        entries += int(fn.cache_info().currsize)
        fn.cache_clear()
        functions += 1
    gc.collect()
    return {"cache_mb": stored / MB, "functions": functions, "entries": entries}


def clear_summary(rec: dict) -> str:
    return (f"MPP: released {rec.get('cache_mb', 0.0):.1f} MB (reusable precompute and grids) "
            f"and cleared {rec['functions']} function cache(s) ({rec['entries']} entries)")


# --- operators, panel and menu entry -----------------------------------------------------

class MPP_OT_compare_with_cycles(bpy.types.Operator):
    """Render the current frame with MPP and with Cycles (reference settings), score MPP
    against Cycles and show the difference in the image 'MPP Difference'"""

    bl_idname = "mpp.compare_with_cycles"
    bl_label = "Compare with Cycles"
    bl_options = {'REGISTER'}

    samples: bpy.props.IntProperty(
        name="Cycles Samples", default=DEFAULT_CYCLES_SAMPLES, min=1, soft_max=4096,
        description="Samples per pixel of the Cycles reference render (more: less noise in "
                    "the reference, slower)")

    @classmethod
    def poll(cls, context):
        scene = context.scene
        if scene is None or scene.camera is None:
            cls.poll_message_set("The scene needs a camera")
            return False
        if not hasattr(scene, "cycles"):
            cls.poll_message_set("Cycles is not available")
            return False
        return True

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        try:
            rec = compare_with_cycles(context.scene, self.samples)
        except Exception as e:  # report instead of a traceback the artist never sees
            self.report({'ERROR'}, f"MPP: compare with Cycles failed: {e}")
            return {'CANCELLED'}
        self.report({'WARNING'} if rec.get("failed") else {'INFO'}, compare_summary(rec))
        return {'FINISHED'}


class MPP_OT_clear_cache(bpy.types.Operator):
    """Free what MPP keeps between renders (the precompute and grids kept for the next
    frame, cached tables)"""

    bl_idname = "mpp.clear_cache"
    bl_label = "Clear MPP Caches"
    bl_options = {'REGISTER'}

    def execute(self, context):
        self.report({'INFO'}, clear_summary(clear_caches()))
        return {'FINISHED'}


class MPP_PT_tools(bpy.types.Panel):
    bl_label = "MPP Tools"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_options = {"DEFAULT_CLOSED"}
    bl_order = 1000  # below the settings panels
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layout = self.layout
        row = layout.row(align=True)
        row.operator(MPP_OT_compare_with_cycles.bl_idname, icon="IMAGE_REFERENCE")
        row.operator(MPP_OT_clear_cache.bl_idname, icon="TRASH")
        rec = last_compare(context.scene)
        if rec and rec.get("rel_rmse") is not None:
            col = layout.column(align=True)
            col.label(text=f"Last: frame {rec['frame']}, Cycles {rec['cycles_samples']} spp")
            col.label(text=f"rel_rmse {rec['rel_rmse']:.4f}   bias {rec['bias']:+.4f}")
            if rec.get("mpp_seconds") is not None and rec.get("cycles_seconds") is not None:
                col.label(text=f"MPP {rec['mpp_seconds']:.2f} s   Cycles {rec['cycles_seconds']:.2f} s")


def draw_render_menu(self, context):
    """Entries in the top bar's Render menu while MPP is the engine."""
    if context.engine != ENGINE:
        return
    layout = self.layout
    layout.separator()
    layout.operator(MPP_OT_compare_with_cycles.bl_idname, icon="IMAGE_REFERENCE")
    layout.operator(MPP_OT_clear_cache.bl_idname, icon="TRASH")


CLASSES = (MPP_OT_compare_with_cycles, MPP_OT_clear_cache, MPP_PT_tools)


def register():
    """Register the operators, the panel and the Render menu entries (a second call does
    nothing)."""
    for cls in CLASSES:
        if not cls.is_registered:
            bpy.utils.register_class(cls)
    menu = getattr(bpy.types, "TOPBAR_MT_render", None)
    if menu is not None:
        menu.remove(draw_render_menu)  # no duplicate entry on a second register()
        menu.append(draw_render_menu)


def unregister():
    menu = getattr(bpy.types, "TOPBAR_MT_render", None)
    if menu is not None:
        menu.remove(draw_render_menu)
    for cls in reversed(CLASSES):
        if cls.is_registered:
            bpy.utils.unregister_class(cls)
