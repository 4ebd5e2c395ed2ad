"""The extension's panels (``ui/``, and the tools panel and Render menu of ``operators/``)
drawn into a recording layout: Blender's background mode draws no UI, so a panel that raises
(a RecursionError, a property renamed in ``scene.mpp``) would otherwise reach the artist
first, as an empty panel and a traceback in the console."""
import types

import pytest

bpy = pytest.importorskip("bpy")

import operators  # noqa: E402  (the repository root's ``operators`` package)
import ui  # noqa: E402  (the repository root's ``ui`` package)

pytestmark = pytest.mark.usefixtures("registered")


class Layout:
    """Records what a draw() asks for; ``prop`` checks that the property exists."""

    def __init__(self, props):
        self.props = props
        self.use_property_split = False
        self.use_property_decorate = True
        self.active = True
        self.enabled = True

    def column(self, **kw):
        return Layout(self.props)

    row = column

    def prop(self, data, name, **kw):
        assert name in data.bl_rna.properties, f"no property {name!r} on {data}"
        self.props.append(name)

    def operator(self, idname, **kw):
        category, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, category), name), idname
        self.props.append(idname)

    def label(self, **kw):
        pass

    def separator(self, **kw):
        pass


def draw(draw_function, panel_class, scene):
    """Run ``draw_function`` as a method of a stand-in for ``panel_class``; what it drew."""
    props = []
    panel = types.SimpleNamespace(layout=Layout(props))
    if hasattr(panel_class, "split_layout"):
        panel.split_layout = types.MethodType(panel_class.split_layout, panel)
    context = types.SimpleNamespace(scene=scene, engine=ui.ENGINE)
    draw_function(panel, context)
    return props, panel.layout


def test_every_render_panel_draws_and_shows_every_setting(empty_scene):
    ui.register()
    try:
        shown = []
        for cls in ui.CLASSES:
            assert cls.poll(types.SimpleNamespace(engine=ui.ENGINE))
            props, layout = draw(cls.draw, cls, empty_scene)
            assert props, cls.__name__
            assert layout.use_property_split and not layout.use_property_decorate, cls.__name__
            shown += props
        settings = [p.identifier for p in empty_scene.mpp.bl_rna.properties
                    if p.identifier not in ("rna_type", "name")]
        assert sorted(set(settings) - set(shown)) == []
        assert "film_transparent" in shown
    finally:
        ui.unregister()


def test_tools_panel_and_render_menu_draw(empty_scene):
    operators.register()
    props, _ = draw(operators.MPP_PT_tools.draw, operators.MPP_PT_tools, empty_scene)
    assert props == ["mpp.compare_with_cycles", "mpp.clear_cache"]
    props, _ = draw(operators.draw_render_menu, object, empty_scene)
    assert props == ["mpp.compare_with_cycles", "mpp.clear_cache"]


# What an artist must see with MPP as the engine, each as the panels that can show it.
NEEDED = {
    "material slots": ("EEVEE_MATERIAL_PT_context_material", "MATERIAL_PT_context_material"),
    "volume material": ("EEVEE_MATERIAL_PT_volume",),
    "world colour": ("EEVEE_WORLD_PT_surface",),
    "light settings": ("DATA_PT_EEVEE_light", "DATA_PT_light"),
    "spot shape": ("DATA_PT_spot",),
    "VDB file": ("DATA_PT_volume_file",),
    "output": ("RENDER_PT_format", "RENDER_PT_output"),
}


def test_stock_panels_show_for_mpp_and_are_given_back():
    ui.register()
    try:
        for what, names in NEEDED.items():
            shown = [n for n in names if ui.ENGINE in getattr(getattr(bpy.types, n, None),
                                                               "COMPAT_ENGINES", ())]
            assert shown, f"no panel shows the {what} for MPP (tried {names})"
    finally:
        ui.unregister()
    assert not any(ui.ENGINE in p.COMPAT_ENGINES for p in ui._stock_panels())
