"""The Blender side of the command line (``mpp_render.cli``), the benchmarks and the tools.

* ``register()``: import bpy and register the engine and its settings (idempotent).
* ``set_mpp``, ``set_cycles_reference``, ``set_multilayer_exr``, ``configure``: engine and
  output settings of a scene (the reference settings of ``shared/reference/metrics.md``).
* ``open_blend(path)``: open a .blend file (``BatchError`` when Blender cannot).
* ``render_current(scene, out_exr)``: render the current frame with the scene's engine, write
  the multilayer EXR and the PNG preview; return the timings record with the passes.
* ``render_frames(scene, paths)``: one frame after another, the record of ``--frames``.
* ``demo(stem, ...)``: the demo cloud rendered with MPP and with Cycles, scored.

Results come back as return values: an MPP render's record is collected from the engine
with ``frame.collect`` around Blender's render operator (``frame.render_mpp``).
"""
from __future__ import annotations

import os
import time

import numpy as np


class BatchError(Exception):
    """Bad input met while rendering (a file Blender cannot open): a message, no bug."""


def register():
    """Import bpy and register the engine and its settings (idempotent); returns bpy."""
    import bpy

    from . import engine, properties

    properties.register()
    engine.register()
    return bpy


def set_cycles_reference(scene, samples=None, multiple=True, seed=0):
    """Cycles settings of the reference images (metrics.md; blender-notes section 4)."""
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device = 'CPU'
    if samples:
        c.samples = int(samples)
    c.seed = int(seed)
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 1024
    c.volume_bounces = 1024 if multiple else 0
    c.transparent_max_bounces = 1024
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = 'BOX'
    c.filter_width = 1.0


def set_mpp(scene, samples=None, multiple=True, seed=None):
    """Select the MPP engine; override its samples / multiple scattering / seed."""
    scene.render.engine = 'MPP_RENDER'
    if samples:
        scene.mpp.samples = int(samples)
    scene.mpp.multiple = bool(multiple)
    if seed is not None:
        scene.mpp.seed = int(seed)


def set_multilayer_exr(scene):
    """Blender's own writer to a 32-bit ZIP multilayer EXR (media_type must come first)."""
    ims = scene.render.image_settings
    ims.media_type = 'MULTI_LAYER_IMAGE'
    ims.file_format = 'OPEN_EXR_MULTILAYER'
    ims.color_depth = '32'
    ims.exr_codec = 'ZIP'


def configure(scene, engine="mpp", samples=None, multiple=True, seed=None,
              resolution_percentage=None) -> None:
    """The command line's settings: ``engine`` 'mpp' or 'cycles' (reference settings, seed
    0 unless given), the resolution percentage when given."""
    if resolution_percentage:
        scene.render.resolution_percentage = resolution_percentage
    if engine == "cycles":
        set_cycles_reference(scene, samples, multiple, seed or 0)
    else:
        set_mpp(scene, samples, multiple, seed)


def open_blend(path: str):
    """Register the engine, open the .blend file ``path`` and return its scene."""
    bpy = register()
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path))
    except RuntimeError as e:
        lines = str(e).strip().splitlines() or ["unknown reason"]
        reason = lines[-1].removeprefix("Error: ")
        raise BatchError(f"Blender cannot open {path} ({reason}); is it a .blend file?") from e
    return bpy.context.scene


def png_path(exr_path: str) -> str:
    """The PNG preview beside ``exr_path``."""
    return os.path.splitext(exr_path)[0] + ".png"


def image_stats(passes: dict) -> dict:
    """A few numbers that describe an image when there is no reference to compare with."""
    comb = passes["Combined"][:, :, :3]
    out = {
        "finite": bool(np.all(np.isfinite(comb))),
        "mean_rgb": [round(float(v), 6) for v in comb.reshape(-1, 3).mean(axis=0)],
        "max": float(np.max(comb)),
    }
    if "Transmittance" in passes:
        out["mean_transmittance"] = round(float(passes["Transmittance"].mean()), 6)
    return out


def render_current(scene, out_exr: str) -> dict:
    """Render ``scene``'s current frame (active view layer) with its engine, write
    ``out_exr`` (multilayer) and the PNG preview; return the timings record.  The record's
    ``"_passes"`` holds the passes (name -> (H, W, C), row 0 at the top) and, for MPP,
    ``"_frame"`` the engine's ``frame.FrameRecord``; both are for callers, not for JSON."""
    import bpy

    from .. import exr
    from .frame import collect

    layer = bpy.context.view_layer.name
    out_exr = os.path.abspath(out_exr)
    os.makedirs(os.path.dirname(out_exr), exist_ok=True)
    t0 = time.perf_counter()
    with collect() as frames:
        bpy.ops.render.render(layer=layer)
    render_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    last = None
    if scene.render.engine == 'MPP_RENDER':
        if not frames:
            raise RuntimeError("the MPP engine produced no image (see the reports above)")
        last = frames[-1]
        passes = last.output.passes
        exr.write_passes(out_exr, passes, layer=last.view_layer)
        exr.write_preview_png(png_path(out_exr), passes["Combined"])
        rec = {"translate": last.translate_s,
               "precompute": last.output.timings.get("precompute"),
               "march": last.output.timings.get("march"),
               "reused": last.output.stats.get("reused", [])}
        extra_write = last.write_s
        warnings = list(last.output.warnings)
        cancelled = last.output.cancelled
    else:
        set_multilayer_exr(scene)
        bpy.data.images["Render Result"].save_render(filepath=out_exr, scene=scene)
        passes = exr.read_passes(out_exr, layer=layer)
        exr.write_preview_png(png_path(out_exr), passes["Combined"])
        rec = {"translate": None, "precompute": None, "march": None}
        extra_write = 0.0
        warnings = []
        cancelled = False
    write_s = time.perf_counter() - t1
    rec.update({"write": extra_write + write_s, "total": render_s + write_s,
                "warnings": warnings, "render": render_s, "engine": scene.render.engine,
                "cancelled": cancelled,
                "resolution": [scene.render.resolution_x * scene.render.resolution_percentage // 100,
                               scene.render.resolution_y * scene.render.resolution_percentage // 100],
                "exr": out_exr})
    rec["_passes"] = passes
    rec["_frame"] = last
    return rec


def public(rec: dict) -> dict:
    """``rec`` without the entries for callers (``_passes``, ``_frame``): the JSON record."""
    return {k: v for k, v in rec.items() if not k.startswith("_")}


def render_frames(scene, paths) -> dict:
    """Render each ``(frame, exr_path)`` of ``paths`` one after the other (scene already
    configured); stops at a cancelled frame.  Returns the ``--frames`` record."""
    records, warnings = [], []
    t0 = time.perf_counter()
    for f, path in paths:
        scene.frame_set(f)
        rec = public(render_current(scene, path))
        rec["frame"] = f
        records.append(rec)
        warnings.extend(w for w in rec["warnings"] if w not in warnings)
        if rec["cancelled"]:
            break
    total = time.perf_counter() - t0
    return {"frames": records, "seconds_per_frame": total / max(1, len(records)),
            "total": total, "warnings": warnings,
            "cancelled": any(r["cancelled"] for r in records)}


def demo(stem: str, samples=None, multiple=True, cycles_samples=32) -> dict:
    """Build the demo cloud, render it with MPP to ``stem.exr``, then with Cycles at the
    reference settings (``cycles_samples`` spp, 0 to skip) to ``stem_cycles.exr`` and score
    ours against it (one Cycles run: the metrics of metrics.md without the noise correction,
    so the error includes Cycles' noise)."""
    register()
    from ..metrics import compare
    from .demo import build_demo_scene

    scene = build_demo_scene(os.path.dirname(os.path.abspath(stem)))
    set_mpp(scene, samples, multiple)
    rec = render_current(scene, stem + ".exr")
    ours = rec["_passes"]
    rec = public(rec)
    rec["image"] = image_stats(ours)
    spp = int(cycles_samples or 0)
    if spp > 0:
        set_cycles_reference(scene, spp, multiple, seed=1)
        ref = render_current(scene, stem + "_cycles.exr")
        m = compare(ours["Combined"], [ref["_passes"]["Combined"]])
        rec["cycles"] = {"samples": spp, "seconds": ref["render"], "exr": ref["exr"],
                         "rel_rmse": m["rel_rmse"], "rel_rmse_4": m["rel_rmse_4"], "bias": m["bias"]}
        set_mpp(scene, samples, multiple)
    return rec
