"""mpp_render: volume rendering by ray marching plus most-probable-path multiple scattering.

This package is the numeric core and must import without Blender; the Blender glue lives in
``mpp_render.blender`` and is imported only by the extension and the command line.
"""

__version__ = "0.1.0"
