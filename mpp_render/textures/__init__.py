"""Blender's procedural textures evaluated on arrays of points (no bpy)."""
