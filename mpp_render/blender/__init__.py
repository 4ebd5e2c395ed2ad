"""Blender glue: the only part of mpp_render that imports ``bpy``.

``translate`` turns an evaluated depsgraph into a bpy-free ``SceneDescription``; ``frame``
renders a depsgraph's frame with ``mpp_render.render`` and returns its record (passes,
timings, warnings); ``engine`` holds the thin ``RenderEngine`` that calls ``frame`` and
copies the passes into Blender's render result; ``batch`` does the command line's Blender
work (engine settings, renders written to EXR, the demo); ``properties`` holds the scene
settings and ``demo`` builds the demo scene.
"""
