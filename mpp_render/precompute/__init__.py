"""Per-light and world-light precompute on each medium's voxel grid.

For every medium we build one *field* array (X, Y, Z, C) float32 on the medium's padded grid,
read by the march with a single trilinear fetch per step (its channels: layout.py), and with
multiple scattering, per light, a light pyramid.  The modules, in the order the precompute
runs them (run.py):

* lattice.py: the voxels that need values, the lattices on the grid, index to world;
* lightdepth.py: optical depth to each light through all media and surfaces (the sweep);
* source.py: the first-scattering source on a lattice and the forward peak's light;
* worldlight.py: the world's light scattered towards the camera;
* skydeficit.py: the sky's light that absorbing media lose once it has scattered (a
  fictitious emission's traced flights, taken off worldlight's multiple scattering);
* emissionlight.py, fogglow.py: the media's glow, scattered in them;
* lightpyramid.py, boundary.py: the walk's levels, their escape through the surface and
  their drift.
"""
from .layout import FieldLayout
from .lightpyramid import MultipleField
from .run import Precomputed, precompute

__all__ = ["FieldLayout", "MultipleField", "Precomputed", "precompute"]
