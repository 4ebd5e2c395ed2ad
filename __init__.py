"""MPP Render as a Blender extension (Blender 4.2+; see blender_manifest.toml).

Installed, this folder is the package ``bl_ext.<repository>.mpp_render`` and the renderer is
its subpackage ``.mpp_render``; run from a checkout (command line, tests) ``mpp_render`` is a
top-level package.  That is why every module inside ``mpp_render/`` imports relatively.

``register()`` adds the settings (``scene.mpp``), the ``MPP_RENDER`` engine and, when they
exist, the extension's ``ui`` and ``operators`` subpackages (next to this file; the command
line renders without them).
"""
import importlib

OPTIONAL = ("ui", "operators")


def _optional_modules():
    """The optional glue modules that exist in this copy, in registration order."""
    found = []
    for name in OPTIONAL:
        full = f"{__package__}.{name}"
        try:
            found.append(importlib.import_module(full))
        except ModuleNotFoundError as e:
            if e.name != full:  # the module exists but one of its imports is missing
                raise
    return found


def _glue():
    """The engine and settings modules, imported when Blender registers the extension (not at
    import, so that this file also imports on its own, e.g. when a test runner that finds it
    at the root of a checkout imports it without its package)."""
    from .mpp_render.blender import engine, properties
    return engine, properties


def register():
    engine, properties = _glue()
    properties.register()
    engine.register()
    for mod in _optional_modules():
        mod.register()


def unregister():
    for mod in reversed(_optional_modules()):
        mod.unregister()
    engine, properties = _glue()
    engine.unregister()
    properties.unregister()
