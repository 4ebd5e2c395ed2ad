"""Render Properties panels of the MPP engine, laid out like Cycles' own, and the stock
Blender panels (light, material, world, volume data) made visible when MPP is the engine.

Imported by the extension's root ``__init__`` as ``.ui``; nothing here is needed to render.
"""
import bpy

ENGINE = "MPP_RENDER"

# Blender's own panels an MPP user needs (light settings, volume materials, world colour,
# VDB data): they show only for engines listed in their COMPAT_ENGINES.  A name this Blender
# lacks is skipped (the material slots are EEVEE_MATERIAL_PT_context_material in 4.2 to 5.0).
STOCK_PANELS = (
    "DATA_PT_context_light", "DATA_PT_light", "DATA_PT_spot", "DATA_PT_EEVEE_light",
    "DATA_PT_context_volume", "DATA_PT_volume_file", "DATA_PT_volume_grids",
    "DATA_PT_volume_render", "DATA_PT_volume_viewport_display",
    "EEVEE_MATERIAL_PT_context_material", "MATERIAL_PT_context_material", "MATERIAL_PT_preview",
    "EEVEE_MATERIAL_PT_surface", "EEVEE_MATERIAL_PT_volume",
    "EEVEE_WORLD_PT_surface", "EEVEE_WORLD_PT_volume", "WORLD_PT_context_world",
    "RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output", "RENDER_PT_color_management",
    "VIEWLAYER_PT_layer",
)


class MPPPanel:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def split_layout(self):
        """The panel's layout with labels beside the values, as Cycles' panels draw."""
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        return layout


class MPP_PT_sampling(MPPPanel, bpy.types.Panel):
    bl_label = "Sampling"

    def draw(self, context):
        layout = self.split_layout()
        mpp = context.scene.mpp
        col = layout.column()
        col.prop(mpp, "quality")
        col.prop(mpp, "samples", text="Render")
        col.prop(mpp, "noise_threshold")
        col.prop(mpp, "viewport_samples")
        col.prop(mpp, "seed")


class MPP_PT_volumes(MPPPanel, bpy.types.Panel):
    bl_label = "Volumes"

    def draw(self, context):
        layout = self.split_layout()
        mpp = context.scene.mpp
        col = layout.column()
        col.prop(mpp, "step_size")
        col.prop(mpp, "voxel_resolution")


class MPP_PT_light_paths(MPPPanel, bpy.types.Panel):
    bl_label = "Light Paths"

    def draw(self, context):
        layout = self.split_layout()
        mpp = context.scene.mpp
        col = layout.column()
        col.prop(mpp, "multiple")
        sub = col.column()
        sub.active = mpp.multiple
        sub.prop(mpp, "multiple_resolution")
        sub.prop(mpp, "multiple_paths")
        sub.prop(mpp, "surface_bounce")
        col.prop(mpp, "surface_cache")
        col.prop(mpp, "ambient_directions")


class MPP_PT_film(MPPPanel, bpy.types.Panel):
    bl_label = "Film"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.split_layout()
        layout.prop(context.scene.render, "film_transparent", text="Transparent")


class MPP_PT_performance(MPPPanel, bpy.types.Panel):
    bl_label = "Performance"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.split_layout()
        layout.prop(context.scene.mpp, "threads")
        layout.prop(context.scene.mpp, "memory_budget_mb")


CLASSES = (MPP_PT_sampling, MPP_PT_volumes, MPP_PT_light_paths, MPP_PT_film, MPP_PT_performance)


def _stock_panels():
    for name in STOCK_PANELS:
        panel = getattr(bpy.types, name, None)
        if panel is not None and hasattr(panel, "COMPAT_ENGINES"):
            yield panel


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for panel in _stock_panels():
        panel.COMPAT_ENGINES.add(ENGINE)


def unregister():
    for panel in _stock_panels():
        panel.COMPAT_ENGINES.discard(ENGINE)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
