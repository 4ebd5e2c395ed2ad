"""The emission a volume's grids or node trees drive (materials.VolumeCoefficients'
``emission_terms``), put on a medium's voxels by the translators (vdb.lattice_emission,
materials.realise).

Cycles' ``svm_node_principled_volume`` and ``svm_node_attr``: the blackbody at a temperature
(times the Temperature Attribute grid), Emission Color x an Attribute node's grid (0 where the
grid does not exist), and colour x strength where node trees drive them.  Each term's
``constant`` is its part of VolumeCoefficients.emission, what meshes and the world render
where no grid exists; ``per_voxel`` gives its emission on the voxels, W/(m^3 sr).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import List, Optional, Union

import numpy as np

from ... import blackbody
from .convert import rgb
from .shadergraph import Field


@dataclass
class BlackbodyTerm:
    """The blackbody emission of one Principled Volume (Cycles' ``svm_node_principled_volume``).

    ``intensity``: Blackbody Intensity (> 0); ``temperature``: Temperature (K); ``attribute``:
    Temperature Attribute (the grid that multiplies the temperature where it exists) or None;
    ``tint``: Blackbody Tint (RGB); ``weight``: the Mix Shader factors on the way;
    ``constant``: weight x its emission at the constant temperature, W/(m^3 sr) (part of
    VolumeCoefficients.emission)."""

    intensity: float
    temperature: float
    attribute: Optional[str]
    tint: np.ndarray
    weight: float = 1.0
    constant: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def scaled(self, w: float) -> "BlackbodyTerm":
        return BlackbodyTerm(self.intensity, self.temperature, self.attribute, self.tint,
                             self.weight * w, self.constant * w)

    def per_voxel(self, grid) -> np.ndarray:
        """weight x emission (..., 3) float32 with T = temperature x max(grid, 0) (W/(m^3 sr))."""
        t = self.temperature * np.maximum(np.nan_to_num(np.asarray(grid, np.float64)), 0.0)
        return (self.weight * blackbody.emission(t, self.intensity, self.tint)).astype(np.float32)


@dataclass
class AttributeEmissionTerm:
    """Emission whose strength an Attribute node gives (linked into Principled Volume's
    Emission Strength or the Emission shader's Strength): ``colour`` (Emission Color, RGB)
    x the value of grid ``attribute``, W/(m^3 sr).  Where the attribute does not exist
    Cycles reads 0, so ``constant`` (the part of VolumeCoefficients.emission) is 0.
    ``socket``: the input's name, for messages; ``weight``: the Mix Shader factors."""

    colour: np.ndarray
    attribute: str
    socket: str = "Emission Strength"
    weight: float = 1.0
    constant: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def scaled(self, w: float) -> "AttributeEmissionTerm":
        return AttributeEmissionTerm(self.colour, self.attribute, self.socket, self.weight * w,
                                     self.constant * w)

    def per_voxel(self, grid) -> np.ndarray:
        """weight x colour x max(grid, 0): (..., 3) float32, W/(m^3 sr)."""
        g = np.maximum(np.nan_to_num(np.asarray(grid, np.float64)), 0.0)
        return (self.weight * g[..., None] * np.asarray(self.colour, np.float64)).astype(np.float32)


@dataclass
class FieldEmissionTerm:
    """Emission whose colour or strength a node tree drives (Principled Volume's Emission
    Color x Emission Strength, an Emission shader's Color x Strength; not scaled by density):
    ``colour`` an RGB array or a Field, ``strength`` a float, a Field, or the name of the grid
    an Attribute node reads (0 where it is missing).  The translators put it on the voxels
    (``per_voxel``); ``constant`` (its part of VolumeCoefficients.emission) is 0.  ``socket``:
    the strength input's name; ``weight``: the Mix Shader factors."""

    colour: object
    strength: object
    socket: str = "Emission Strength"
    weight: float = 1.0
    constant: np.ndarray = field(default_factory=lambda: np.zeros(3))
    attribute = None  # no grid by name of its own (vdb.lattice_emission passes it by)

    def scaled(self, w: float) -> "FieldEmissionTerm":
        return dataclasses.replace(self, weight=self.weight * w)

    def fields(self) -> List[Field]:
        return [f for f in (self.colour, self.strength) if isinstance(f, Field)]

    def grids(self) -> List[str]:
        return [self.strength] if isinstance(self.strength, str) else []

    def per_voxel(self, sample, grid_of) -> np.ndarray:
        """weight x colour x strength at the lattice ``sample`` evaluates fields on (..., 3)
        float32, >= 0."""
        c = sample(self.colour) if isinstance(self.colour, Field) else rgb(self.colour)
        if isinstance(self.strength, Field):
            s = sample(self.strength)
        elif isinstance(self.strength, str):
            grid = grid_of(self.strength)
            s = np.zeros(()) if grid is None else np.maximum(np.nan_to_num(grid), 0.0)
        else:
            s = np.asarray(float(self.strength))
        out = self.weight * np.asarray(s, np.float64)[..., None] * np.asarray(c, np.float64)
        return np.maximum(np.nan_to_num(out), 0.0).astype(np.float32)


@dataclass
class FieldBlackbodyTerm:
    """Principled Volume's blackbody with its Temperature driven by a node tree: T = the field
    x max(grid ``grid``, 0) where that grid (Temperature Attribute) exists, else the field;
    ``intensity``, ``tint``, ``weight`` as :class:`BlackbodyTerm`.  Put on the voxels by the
    translators; ``constant`` is 0."""

    intensity: float
    temperature: Field
    grid: Optional[str]
    tint: np.ndarray
    weight: float = 1.0
    constant: np.ndarray = field(default_factory=lambda: np.zeros(3))
    attribute = None

    def scaled(self, w: float) -> "FieldBlackbodyTerm":
        return dataclasses.replace(self, weight=self.weight * w)

    def fields(self) -> List[Field]:
        return [self.temperature]

    def grids(self) -> List[str]:
        return [self.grid] if self.grid else []

    def per_voxel(self, sample, grid_of) -> np.ndarray:
        t = np.asarray(sample(self.temperature), np.float64)
        grid = grid_of(self.grid) if self.grid else None
        if grid is not None:
            t = t * np.maximum(np.nan_to_num(np.asarray(grid, np.float64)), 0.0)
        return (self.weight * blackbody.emission(t, self.intensity, self.tint)).astype(np.float32)


EmissionTerm = Union[BlackbodyTerm, AttributeEmissionTerm, FieldEmissionTerm, FieldBlackbodyTerm]
FIELD_TERMS = (FieldEmissionTerm, FieldBlackbodyTerm)
