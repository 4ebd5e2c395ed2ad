"""Blender glue: the only part of mpp_render that imports ``bpy``.

``translate`` turns an evaluated depsgraph into a bpy-free ``SceneDescription``; ``engine``
holds the thin ``RenderEngine`` that hands it to ``mpp_render.render`` and writes the passes.
"""
