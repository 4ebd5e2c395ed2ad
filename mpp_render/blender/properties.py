"""The engine's settings as Blender properties: ``scene.mpp`` (a PropertyGroup), and
``settings_from_scene`` that copies them into the bpy-free ``mpp_render.scene.Settings``.

Defaults match ``Settings``'s, so a file that never touched the panel renders as the core's
defaults do.
"""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from ..scene import MULTIPLE_PATHS, QUALITY_PRESETS, Settings


def _refresh_passes(self, context):
    """Multiple scattering on/off adds/removes the Volume Multiple pass: let every view layer
    of the scene (and the compositor's Render Layers node) see the new list."""
    for view_layer in self.id_data.view_layers:
        view_layer.update_render_passes()


def _apply_quality(self, context):
    """The Quality menu writes its preset's samples, paths and resolution (scene.py)."""
    for name, value in QUALITY_PRESETS[self.quality].items():
        setattr(self, name, value)


class MPPRenderSettings(bpy.types.PropertyGroup):
    """Per-scene settings of the MPP engine (``scene.mpp``)."""

    quality: EnumProperty(
        name="Quality", default="FINAL", update=_apply_quality,
        items=[("PREVIEW", "Preview", "4 samples and the fast most-probable-path model of "
                "multiple scattering: smooth, seconds, but biased (public scenes: error median "
                "0.09, worst 1.8; 4 s median at 160x120)"),
               ("FINAL", "Final", "16 samples at most (adaptive, Noise Threshold 0.02) and 3 "
                "million traced light paths per light for multiple scattering: the defaults "
                "(public scenes: error median 0.018, worst 0.14; 10 s median at 160x120)"),
               ("REFERENCE", "Reference", "16 samples in every pixel (Noise Threshold 0), 12 "
                "million paths per light on a lattice twice as fine: closest to Cycles, "
                "3-11x Final's time, 12-22x on VDBs (public scenes: error median 0.016, 90th "
                "percentile 0.05; 67 s median at 160x120)")],
        description="Sets Samples, Noise Threshold, Multiple Scattering Paths and Resolution "
                    "together "
                    "(they stay editable). docs/usage.md gives each one's time and error on "
                    "the public scenes")

    samples: IntProperty(
        name="Samples", default=16, min=1, soft_max=1024,
        description="Camera rays per pixel, jittered over the pixel square (1 px box filter). "
                    "More samples: less noise and aliasing, proportionally longer march")
    noise_threshold: FloatProperty(
        name="Noise Threshold", default=0.02, min=0.0, soft_max=0.1, precision=4,
        description="Adaptive sampling: a pixel stops taking samples once its noise (the "
                    "standard error of its mean, over the square root of that mean times "
                    "the frame's mean brightness) is below this: the relative noise the "
                    "frame keeps, at any exposure. A pilot finds the noisy places; the rest "
                    "take 1 sample. Higher: faster, noisier. 0 = every pixel takes all its "
                    "samples")
    viewport_samples: IntProperty(
        name="Viewport", default=16, min=1, soft_max=1024,
        description="Camera rays per pixel of the Rendered viewport's last picture. The "
                    "viewport first shows a coarse picture (a quarter of the resolution, 1 "
                    "sample), then the full resolution at 1, 4, 16, ... samples up to this "
                    "count: with the render's samples, the last picture is the F12 render "
                    "of that view")
    step_size: FloatProperty(
        name="Step Size", default=0.0, min=0.0, soft_max=1.0, precision=4, subtype='DISTANCE',
        unit='LENGTH',
        description="Ray-march step along camera rays, in metres (scene units). "
                    "0 = automatic: half the finest voxel of the volumes in the scene")
    voxel_resolution: IntProperty(
        name="Voxel Resolution", default=128, min=8, soft_max=512,
        description="Voxels along the longest side when a mesh volume (an object with a "
                    "volume material) is turned into a density grid. Dimensionless count")
    multiple: BoolProperty(
        name="Multiple Scattering", default=True, update=_refresh_passes,
        description="Add light scattered more than once (most-probable-path approximation), "
                    "filling the Volume Multiple pass. Off: single scattering only")
    multiple_resolution: IntProperty(
        name="Multiple Scattering Resolution", default=64, min=8, soft_max=256,
        description="Points (count) along a volume's longest side of the light pyramid that "
                    "multiple scattering is looked up in (never finer than the voxels). More: "
                    "sharper multiply scattered light, slower precompute. The Volume Multiple "
                    "pass also shifts in brightness with it (measured between 16 and 128: "
                    "within 10% in the public smoke and clouds, up to 25% in thin slabs; "
                    "docs/ms_resolution.md). The world fog's far box takes as many voxels "
                    "along its longest side. The accuracy figures in the docs are at 64")
    multiple_paths: IntProperty(
        name="Multiple Scattering Paths", default=MULTIPLE_PATHS, min=0, soft_max=20_000_000,
        description="Light paths (count) traced per light and volume for the multiply "
                    "scattered light. More: less noise in it (it converges to Cycles' as "
                    "paths and resolution grow), a longer precompute. 0 = the fast "
                    "most-probable-path model instead (smooth, but biased: docs/accuracy.md)")
    surface_bounce: BoolProperty(
        name="Surface Bounce", default=True,
        description="Surfaces (a ground, a wall) reflect light into the volumes, diffusely: "
                    "the light paths start where the lights and the sky light the surfaces, "
                    "out to 64 times a volume's size, and bounce off them (with "
                    "Light Paths 0, flat surfaces reflect the lights once, as area lights, "
                    "none under a World volume). Indirect light: with Multiple Scattering on. "
                    "Off: the surfaces only absorb")
    surface_cache: BoolProperty(
        name="Surface Light Cache", default=True,
        description="The light a surface (a ground, a wall) receives from the sky, the "
                    "volumes and the other surfaces is gathered once on a grid over the image "
                    "(240 points across) and interpolated: a ground under smoke or in fog "
                    "renders several times faster and smoother. Off: every sample gathers "
                    "it (unbiased, noisier, slower; the Reference quality)")
    ambient_directions: IntProperty(
        name="Ambient Directions", default=32, min=1, soft_max=512,
        description="Directions (count) per voxel used to integrate the world light's "
                    "transmittance through the volumes. More: smoother sky lighting, slower "
                    "precompute")
    threads: IntProperty(
        name="Threads", default=0, min=0, soft_max=256,
        description="Worker threads (count) for precompute and march. 0 = one per CPU core")
    memory_budget_mb: IntProperty(
        name="Memory Budget", default=2048, min=0, soft_max=65536,
        description="Memory in MB (megabytes, 2^20 bytes) the precomputed light fields of the "
                    "volumes may take. A larger grid is downsampled (coarser voxels) with a "
                    "warning giving the factor. 0 = unlimited")
    seed: IntProperty(
        name="Seed", default=0, min=0,
        description="Seed of the pixel jitter and sampled directions (integer): the same "
                    "seed gives the same image")


def settings_from_scene(scene) -> Settings:
    """A ``Settings`` from ``scene.mpp`` and ``scene.render.film_transparent``; every pass the
    engine has is filled (``passes`` None)."""
    p = scene.mpp
    return Settings(
        samples=int(p.samples),
        noise_threshold=float(f"{p.noise_threshold:.6g}"),   # the float32 property as typed
        step_size=float(p.step_size),
        multiple=bool(p.multiple),
        film_transparent=bool(scene.render.film_transparent),
        seed=int(p.seed),
        ambient_directions=int(p.ambient_directions),
        multiple_resolution=int(p.multiple_resolution),
        multiple_paths=int(p.multiple_paths),
        passes=None,
        threads=int(p.threads),
        voxel_resolution=int(p.voxel_resolution),
        memory_budget_mb=int(p.memory_budget_mb),
        surface_bounce=bool(p.surface_bounce),
        surface_cache=bool(p.surface_cache),
    )


def register():
    """Register the settings group and ``Scene.mpp`` (a second call does nothing)."""
    if MPPRenderSettings.is_registered:
        return
    bpy.utils.register_class(MPPRenderSettings)
    bpy.types.Scene.mpp = PointerProperty(type=MPPRenderSettings, name="MPP Render",
                                          description="Settings of the MPP render engine")


def unregister():
    if not MPPRenderSettings.is_registered:
        return
    if hasattr(bpy.types.Scene, "mpp"):
        del bpy.types.Scene.mpp
    bpy.utils.unregister_class(MPPRenderSettings)
