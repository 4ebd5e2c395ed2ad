"""Volume shading of Blender materials, reduced to coefficients (surfaces: surfaceshading.py;
the emission that grids and fields drive: emissionterms.py).

Volume shaders follow Cycles (``svm_closure.h``); for a closure reached with weight ``w``
(Mix Shader factors) and a density ``d`` (the Density input, >= 0):

* Principled Volume: sigma_s = Color * d,
  sigma_a = max(1 - Color, 0) * max(1 - sqrt(Absorption Color), 0) * d,
  emission = Emission Color * Emission Strength (not scaled by density); the grid named by
  'Density Attribute' multiplies d where it exists (VDB volumes, smoke domains), so the
  coefficients are returned *per unit of that grid*.  With Blackbody Intensity > 0 it also
  emits blackbody.emission(T, Blackbody Intensity, Blackbody Tint) with T = Temperature
  (kelvin), times the grid named by 'Temperature Attribute' where it exists.
* Volume Scatter: sigma_s = Color * d.  Volume Absorption: sigma_a = max(1 - Color, 0) * d.
* Volume Coefficients: sigma_a, sigma_s and emission are the node's coefficient vectors.
* Emission (in a Volume output): emission = Color * Strength.

Emission that a grid drives -- the blackbody term, and an Attribute node linked into
Principled Volume's Emission Strength or the Emission shader's Strength (Cycles'
``svm_node_principled_volume`` and ``svm_node_attr``: emission = Emission Color x the
attribute's value, 0 where the attribute does not exist) -- is listed in
``VolumeCoefficients.emission_terms`` (:class:`BlackbodyTerm`, :class:`AttributeEmissionTerm`);
``emission`` holds each term's value where its grid is missing (``constant``: the blackbody
at the constant Temperature, 0 for an attribute), which is what meshes and the world render.
A reader of grids (vdb.py for Volume objects and, through the same helper, fluid.py for
smoke domains: ``vdb.lattice_emission``) replaces that constant by the per-voxel emission.

Inputs driven by node trees (*fields*, ``shadergraph.Field``; evaluated where the values are
needed, at a medium's voxels, by ``realise``):

* Density (Principled Volume, Volume Scatter, Volume Absorption): the closure's coefficients
  are per unit of the field, ``VolumeCoefficients.density_field``; the medium's density grid
  is its mask or grid x max(field, 0) (Cycles clamps the density at 0 and multiplies it by
  the Density Attribute grid where that exists).
* Emission Strength / Emission Color (and an Emission shader's Strength / Color): a
  :class:`FieldEmissionTerm`, colour x strength per voxel; Temperature (with Blackbody
  Intensity > 0): a :class:`FieldBlackbodyTerm`, T = field x the Temperature Attribute grid
  where it exists.
* Color / Absorption Color: a :class:`ColourMean` evaluates the closure's coefficients at
  every voxel.  The medium's coefficients are their density-weighted means; the scattering
  varies per voxel through its factor on that mean (``Realised.scatter_grid``,
  Medium.scatter_grid), the extinction's brightness per voxel goes into the density, and
  where the extinction's colour varies too (a coloured Absorption Color field, a Volume
  Scatter's or Absorption's coloured field) its factor per channel on the mean
  (``Realised.extinction_grid``, Medium.extinction_grid).  A Principled Volume's Color
  field with a constant black Absorption Color leaves the extinction the density itself.
  Its Color Attribute (a grid, e.g. a smoke domain's 'color') multiplies Color the same
  way, per voxel, where the object has that grid.
* Any other input (Anisotropy, Blackbody Intensity, a surface's inputs, ...) driven by a
  field that varies in space takes the socket's own value, with a warning.  A field that
  does not vary (Math on constants) is a constant; nodes a field cannot evaluate are named
  in a warning and replaced by their input's value.

Coefficients are in 1/m, emission in W/(m^3 sr).  Closures that read the same density source
add; their anisotropies combine as the mean weighted by each closure's mean sigma_s.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Dict, List, NamedTuple, Optional, Tuple

import numpy as np

from ... import blackbody
from .convert import fmt, rgb, scalar
from .emissionterms import (FIELD_TERMS, AttributeEmissionTerm, BlackbodyTerm, EmissionTerm,
                            FieldBlackbodyTerm, FieldEmissionTerm)
from .nodes import Closure, closures, describe, output_node, resolve
from .shadergraph import Field

HG = "HENYEY_GREENSTEIN"


@dataclass
class ColourMean:
    """A closure whose Color or Absorption Color varies in space: ``build(colours)`` ->
    (sigma_s, sigma_a) per unit density (1/m) with ``colours`` (every input name -> RGB, or
    (N, 3) per voxel): the constants ``consts``, the values of ``fields`` (input name ->
    Field), each times the grid ``attributes`` names for it where that grid exists (a
    Principled Volume's Color Attribute: Cycles multiplies Color by it, and leaves Color as
    it is where the object has no such grid) (``realise``).  ``g``: the closure's
    anisotropy; ``weight``: the Mix Shader factors."""

    fields: Dict[str, Field]
    build: Callable[[Dict[str, np.ndarray]], Tuple[np.ndarray, np.ndarray]]
    g: float = 0.0
    weight: float = 1.0
    consts: Dict[str, np.ndarray] = field(default_factory=dict)
    attributes: Dict[str, str] = field(default_factory=dict)

    def scaled(self, w: float) -> "ColourMean":
        return dataclasses.replace(self, weight=self.weight * w)


@dataclass
class VolumeCoefficients:
    """Constant coefficients of the closures that share one density source.

    ``attribute``: the grid (geometry attribute) whose value multiplies the coefficients, or
    None for a uniform density.  ``from_attribute_node``: the attribute comes from an
    Attribute node linked into a Density input (rather than Principled Volume's 'Density
    Attribute').  ``sigma_s``, ``sigma_a``: RGB 1/m per unit density; ``g``: anisotropy;
    ``emission``: RGB W/(m^3 sr), not scaled by density (the emission terms included at
    their ``constant``); ``emission_terms``: the emission that grids and fields drive
    (:class:`BlackbodyTerm`, :class:`AttributeEmissionTerm`, :class:`FieldEmissionTerm`,
    :class:`FieldBlackbodyTerm`).  ``density_field``: a Field the density is multiplied by
    (None: none); ``colour_means``: closures whose colours fields drive (:class:`ColourMean`;
    their coefficients are not yet in ``sigma_s``/``sigma_a``)."""

    attribute: Optional[str]
    sigma_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sigma_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    g: float = 0.0
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    from_attribute_node: bool = False
    emission_terms: List[EmissionTerm] = field(default_factory=list)
    density_field: Optional[Field] = None
    colour_means: List[ColourMean] = field(default_factory=list)


def principled_coefficients(color, density: float, absorption_color):
    """(sigma_s, sigma_a) 1/m of Cycles' Principled Volume for RGB ``color`` and
    ``absorption_color`` (arrays (..., 3), broadcast) and a density >= 0."""
    c = np.asarray(color, np.float64)
    ac = np.sqrt(np.maximum(np.asarray(absorption_color, np.float64), 0.0))
    absorption = np.maximum(1.0 - c, 0.0) * np.maximum(1.0 - ac, 0.0)
    return np.maximum(c * density, 0.0), absorption * density


def principled_volume(color, density, anisotropy, absorption_color, emission=(0.0, 0.0, 0.0),
                      attribute: Optional[str] = "density") -> VolumeCoefficients:
    """Cycles' Principled Volume coefficients (see the module docstring)."""
    ss, sa = principled_coefficients(rgb(color), max(float(density), 0.0),
                                     rgb(absorption_color))
    return VolumeCoefficients(attribute, ss, sa, float(anisotropy), rgb(emission))


def default_volume() -> VolumeCoefficients:
    """What a Volume object without a material renders like: a default Principled Volume
    (Color 0.5, Density 1 x the 'density' grid, no absorption colour, anisotropy 0)."""
    return principled_volume((0.5, 0.5, 0.5), 1.0, 0.0, (0.0, 0.0, 0.0))


class ClosureInputs:
    """The inputs of one closure node: constants, attributes and fields; warns about the
    inputs it cannot give (and about nodes a field cannot evaluate)."""

    def __init__(self, closure: Closure, where: str, warnings: List[str]):
        self.closure, self.where, self.warnings = closure, where, warnings

    def raw(self, name, allow_attribute=False, allow_field=False):
        """``(value, attribute)`` of input ``name``.  A field that does not vary gives its
        value; one that varies is returned as the value when ``allow_field`` (a
        :class:`~.shadergraph.Field`), else the socket's own value is used with a warning;
        an attribute is returned when allowed, else likewise."""
        node = self.closure.node
        socket = node.inputs.get(name)
        if socket is None:
            return None, None
        res = resolve(socket, self.closure.stack)
        if res.attribute is not None and allow_attribute:
            return 1.0, res.attribute
        if res.field is not None:
            f = res.field
            self.warnings.extend(f.messages(self.where))
            if not f.varies:
                return f.constant(), None
            if allow_field:
                return f, None
            self.warnings.append(
                f"{self.where}: {f.describe()} varies in space, which the MPP engine does not "
                f"support for this input; using the input's value {fmt(socket.default_value)}")
            return _plain(socket.default_value), None
        if res.value is None:
            culprit = _culprit(res)
            self.warnings.append(
                f"{self.where}: {culprit} linked into '{name}' of {describe(node)} is not "
                f"supported; using the input's value {fmt(socket.default_value)}")
            return _plain(socket.default_value), None
        return res.value, None

    def color(self, name) -> np.ndarray:
        return rgb(self.raw(name)[0])

    def number(self, name) -> float:
        return scalar(self.raw(name)[0])


def _plain(v):
    return v if isinstance(v, (int, float, str)) else tuple(v)


def _phase_g(node, inputs: ClosureInputs, where, warnings) -> float:
    """Anisotropy of a scattering node; other phase functions become Henyey-Greenstein."""
    phase = getattr(node, "phase", HG)
    if phase == HG:
        return inputs.number("Anisotropy")
    g = 0.0 if phase == "RAYLEIGH" else inputs.number("Anisotropy")
    warnings.append(f"{where}: phase function {phase} of {describe(node)} is not supported; "
                    f"using Henyey-Greenstein with anisotropy {g:g}")
    return g


def _density(inp: "ClosureInputs"):
    """``(d, attribute, field)`` of a closure's Density: d >= 0 the constant density (1 when
    an attribute or a field gives it), the attribute an Attribute node reads, the Field."""
    dens, attr = inp.raw("Density", allow_attribute=True, allow_field=True)
    if isinstance(dens, Field):
        return 1.0, attr, dens
    return max(scalar(dens), 0.0), attr, None


def _colours(inp: "ClosureInputs", names) -> Tuple[Dict[str, np.ndarray], Dict[str, Field]]:
    """The constant colours and the fields among the inputs ``names``."""
    consts, fields = {}, {}
    for name in names:
        v = inp.raw(name, allow_field=True)[0]
        if isinstance(v, Field):
            fields[name] = v
        else:
            consts[name] = rgb(v)
    return consts, fields


def _with_colours(co: "VolumeCoefficients", consts, fields, build, g: float,
                  attributes: Optional[Dict[str, str]] = None):
    """``co`` with the coefficients ``build(colours)`` -> (sigma_s, sigma_a): now when every
    colour is constant and no grid multiplies one (``attributes``: input name -> grid name),
    else deferred to the voxels (:class:`ColourMean`)."""
    if not fields and not attributes:
        co.sigma_s, co.sigma_a = build(consts)
        return co
    co.colour_means = [ColourMean(fields, build, g, consts=consts,
                                  attributes=dict(attributes or {}))]
    return co


def _volume_closure(c: Closure, where, warnings):
    """The :class:`VolumeCoefficients` of one closure (before its Mix weight), or None (with
    a warning) when the node is not a volume shader."""
    node, kind = c.node, c.node.bl_idname
    inp = ClosureInputs(c, where, warnings)
    if kind == "ShaderNodeVolumePrincipled":
        d, linked_attr, dfield = _density(inp)
        attr = inp.raw("Density Attribute")[0] or None
        if linked_attr is not None and attr is not None:
            warnings.append(f"{where}: attribute '{linked_attr}' linked into 'Density' of "
                            f"{describe(node)} is not supported together with its Density "
                            f"Attribute '{attr}'; using Density 1")
            linked_attr = None
        color_attr = inp.raw("Color Attribute")[0]
        emission, terms = _emission(inp, "Emission Color", "Emission Strength")
        g = inp.number("Anisotropy")
        consts, fields = _colours(inp, ("Color", "Absorption Color"))

        def build(colours):
            return principled_coefficients(colours["Color"], max(float(d), 0.0),
                                           colours["Absorption Color"])

        co = _with_colours(VolumeCoefficients(linked_attr or attr, g=g, emission=rgb(emission)),
                           consts, fields, build, g,
                           {"Color": color_attr} if color_attr else None)
        co.from_attribute_node = linked_attr is not None
        co.density_field = dfield
        co.emission_terms = terms
        b = inp.number("Blackbody Intensity")
        if b > 0.0:
            t = inp.raw("Temperature", allow_field=True)[0]
            tint = inp.color("Blackbody Tint")
            grid = inp.raw("Temperature Attribute")[0] or None
            if isinstance(t, Field):
                co.emission_terms = co.emission_terms + [FieldBlackbodyTerm(b, t, grid, tint)]
            else:
                t = scalar(t)
                term = BlackbodyTerm(b, t, grid, tint, constant=blackbody.emission(t, b, tint))
                co.emission = co.emission + term.constant
                co.emission_terms = co.emission_terms + [term]
        return co
    if kind in ("ShaderNodeVolumeScatter", "ShaderNodeVolumeAbsorption"):
        d, attr, dfield = _density(inp)
        co = VolumeCoefficients(attr, from_attribute_node=attr is not None, density_field=dfield)
        consts, fields = _colours(inp, ("Color",))
        if kind == "ShaderNodeVolumeScatter":
            co.g = _phase_g(node, inp, where, warnings)
            return _with_colours(co, consts, fields,
                                 lambda cs: (np.maximum(cs["Color"], 0.0) * d, np.zeros(3)), co.g)
        return _with_colours(co, consts, fields,
                             lambda cs: (np.zeros(3), np.maximum(1.0 - cs["Color"], 0.0) * d), 0.0)
    if kind == "ShaderNodeVolumeCoefficients":
        return VolumeCoefficients(
            None, np.maximum(inp.color("Scatter Coefficients"), 0.0),
            np.maximum(inp.color("Absorption Coefficients"), 0.0),
            _phase_g(node, inp, where, warnings), inp.color("Emission Coefficients"))
    if kind == "ShaderNodeEmission":
        emission, terms = _emission(inp, "Color", "Strength")
        return VolumeCoefficients(None, emission=emission, emission_terms=terms)
    warnings.append(f"{where}: {describe(node)} is not a supported volume shader; ignored")
    return None


def _emission(inp: ClosureInputs, colour: str, strength: str):
    """``(constant emission RGB, [terms])`` of a colour x strength pair of inputs: a field
    in either makes a :class:`FieldEmissionTerm`; an Attribute node linked into the strength
    (with a constant colour) an :class:`AttributeEmissionTerm` (0 where the grid is
    missing); else the product is constant."""
    value, attr = inp.raw(strength, allow_attribute=True, allow_field=True)
    c = inp.raw(colour, allow_field=True)[0]
    if isinstance(c, Field) or isinstance(value, Field):
        s = attr if attr is not None else (value if isinstance(value, Field) else scalar(value))
        c = c if isinstance(c, Field) else rgb(c)
        return np.zeros(3), [FieldEmissionTerm(c, s, socket=strength)]
    c = rgb(c)
    if attr is not None:
        return np.zeros(3), [AttributeEmissionTerm(c, attr, socket=strength)]
    return c * scalar(value), []


def _culprit(res) -> str:
    """What makes a resolved input non-constant, for messages."""
    if res.attribute is not None:
        return f"attribute '{res.attribute}'"
    if res.unsupported is not None:
        return f"node {describe(res.unsupported)}"
    if res.field is not None:
        names = ", ".join(f"'{n}'" for n in res.field.nodes) or "nodes"
        return f"a node tree ({names}) that varies in space"
    return "a link"


def _mix_warning(where, warnings):
    def warn(node, res):
        if res.field is not None:
            warnings.extend(res.field.messages(where))
            if not res.field.varies:
                return
        culprit = _culprit(res)
        warnings.append(f"{where}: {culprit} linked into the factor of {describe(node)} is not "
                        f"supported; using its value {fmt(node.inputs[0].default_value)}")
    return warn


def output_closures(tree, socket_name, where, warnings) -> List[Closure]:
    out = output_node(tree)
    if out is None:
        return []
    socket = out.inputs.get(socket_name)
    return closures(socket, on_unsupported=_mix_warning(where, warnings))


def is_linked(tree, socket_name) -> bool:
    """Whether the active output of ``tree`` has something linked into ``socket_name``."""
    out = output_node(tree)
    socket = out.inputs.get(socket_name) if out is not None else None
    return bool(socket is not None and socket.is_linked)


def _field_key(co: VolumeCoefficients):
    return co.density_field.key if co.density_field is not None else None


def _add(acc: VolumeCoefficients, co: VolumeCoefficients, w: float) -> float:
    """Add closures ``co`` with weight ``w`` into ``acc``; returns the weight of co's
    anisotropy in the mean (w x its mean sigma_s), which the caller divides by."""
    acc.sigma_s = acc.sigma_s + w * co.sigma_s
    acc.sigma_a = acc.sigma_a + w * co.sigma_a
    acc.emission = acc.emission + w * co.emission
    acc.emission_terms = acc.emission_terms + [t.scaled(w) for t in co.emission_terms]
    acc.colour_means = acc.colour_means + [m.scaled(w) for m in co.colour_means]
    s = w * float(np.mean(co.sigma_s))
    acc.g += s * co.g
    return s


def volume_shading(material, where: str, warnings: List[str],
                   grids: bool = False) -> Optional[List[VolumeCoefficients]]:
    """The volume coefficients of ``material``, one entry per density source (a grid name,
    an Attribute node, a density field); None when the material has no volume shader
    (nothing linked into its output's 'Volume').  Without ``grids`` (meshes, the world:
    nothing to read attributes from) an Attribute node driving an emission strength is
    warned about: it gives 0 there, as in Cycles."""
    tree = getattr(material, "node_tree", None)
    if tree is None or not is_linked(tree, "Volume"):
        return None
    groups: Dict[Tuple, VolumeCoefficients] = {}
    g_weight: Dict[Tuple, float] = {}
    for c in output_closures(tree, "Volume", where, warnings):
        co = _volume_closure(c, where, warnings)
        if co is None:
            continue
        key = (co.attribute, co.from_attribute_node, _field_key(co))
        acc = groups.setdefault(key, VolumeCoefficients(co.attribute,
                                                        from_attribute_node=co.from_attribute_node,
                                                        density_field=co.density_field))
        g_weight[key] = g_weight.get(key, 0.0) + _add(acc, co, c.weight)
        if not grids:
            for t in co.emission_terms:
                if isinstance(t, AttributeEmissionTerm) or (
                        isinstance(t, FieldEmissionTerm) and isinstance(t.strength, str)):
                    name = t.attribute if isinstance(t, AttributeEmissionTerm) else t.strength
                    warnings.append(f"{where}: attribute '{name}' linked into "
                                    f"'{t.socket}' of {describe(c.node)} has no values here "
                                    "(only Volume objects and smoke domains have grids); that "
                                    "emission is 0, as in Cycles")
    for key, acc in groups.items():
        acc.g = acc.g / g_weight[key] if g_weight[key] > 0.0 else 0.0
    return list(groups.values())


def merge(groups: List[VolumeCoefficients]) -> VolumeCoefficients:
    """All density sources of a material added into one uniform set of coefficients (with
    the groups' emission terms and colour means; the density field of the first group that
    has one -- use ``merge_by_field`` for groups with different density fields)."""
    out = VolumeCoefficients(None)
    sw = 0.0
    for co in groups:
        sw += _add(out, co, 1.0)
        if out.density_field is None:
            out.density_field = co.density_field
    out.g = out.g / sw if sw > 0.0 else 0.0
    return out


def merge_by_field(groups: List[VolumeCoefficients]) -> List[VolumeCoefficients]:
    """``groups`` merged into one uniform set per density field (the groups without one
    together), in the order they first appear."""
    by: Dict[Optional[str], List[VolumeCoefficients]] = {}
    for co in groups:
        by.setdefault(_field_key(co), []).append(co)
    return [merge(same) for same in by.values()]


# -- fields on a lattice --------------------------------------------------------------------

def has_fields(co: VolumeCoefficients) -> bool:
    """Whether closures ``co`` need fields evaluated (``realise``)."""
    return (co.density_field is not None or bool(co.colour_means)
            or any(isinstance(t, FIELD_TERMS) for t in co.emission_terms))


def field_grids(shading: List[VolumeCoefficients]) -> List[str]:
    """The grid names the fields of ``shading`` read (Attribute and Volume Info nodes inside
    them, a field blackbody's Temperature Attribute, an attribute-driven strength next to a
    field colour), in order, once each."""
    names: List[str] = []
    for co in shading:
        fields = [co.density_field] if co.density_field is not None else []
        for m in co.colour_means:
            fields += list(m.fields.values())
            names += list(m.attributes.values())
        for t in co.emission_terms:
            if isinstance(t, FIELD_TERMS):
                fields += t.fields()
                names += t.grids()
        for f in fields:
            names += f.attributes()
    return list(dict.fromkeys(names))


def colour_grids(shading: List[VolumeCoefficients]) -> List[str]:
    """The grids that multiply colours in ``shading`` (Color Attributes), in order, once
    each: a reader may give them as vector grids (X, Y, Z, 3)."""
    return list(dict.fromkeys(a for co in shading for m in co.colour_means
                              for a in m.attributes.values()))


def weighted_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The mean of ``values`` (shape + (3,)) weighted by ``weights`` (shape; the plain mean
    where all weights are 0)."""
    v = np.nan_to_num(np.asarray(values, np.float64)).reshape(-1, 3)
    w = np.maximum(np.nan_to_num(np.asarray(weights, np.float64)).reshape(-1), 0.0)
    total = w.sum()
    return (w @ v) / total if total > 0.0 else v.mean(axis=0)


class Realised(NamedTuple):
    """Closures on a lattice (``realise``): ``density`` float32 (shape), ``coefficients``
    (no fields left), ``emission_grid`` None or float32 shape + (3,) (W/(m^3 sr)),
    ``scatter_grid`` None or float32 shape + (3,), the factor on ``coefficients.sigma_s``
    per point (Medium.scatter_grid), and ``extinction_grid`` None or float32 shape + (3,),
    the factor on the coefficients' sigma_t per point (Medium.extinction_grid)."""
    density: np.ndarray
    coefficients: VolumeCoefficients
    emission_grid: Optional[np.ndarray]
    scatter_grid: Optional[np.ndarray]
    extinction_grid: Optional[np.ndarray] = None


# Relative spread of the extinction's colour over the voxels above which realise gives it a
# factor per voxel (float32 rounding of the fields is far below it).
EXTINCTION_SPREAD = 1e-3


def realise(co: VolumeCoefficients, base, sample, grid_of, where: str, warnings: List[str],
            per_point: bool = True) -> Realised:
    """Closures ``co`` on a lattice (:class:`Realised`).

    ``base``: the density before the fields (a mesh's inside mask, a grid's values), float32;
    ``sample(field)``: the field's values at the lattice points (``shadergraph.Sampler``);
    ``grid_of(name)``: a grid's values there or None.  The density is ``base`` x max(density
    field, 0).  The colour fields (:class:`ColourMean`) give each point's coefficients:
    where they change the extinction's brightness, the density is times it
    (``_colour_fields``); the medium's coefficients are their means weighted by the density,
    the scattering's factor on its mean per point the scatter grid and the extinction's the
    extinction grid (each None where it is 1 everywhere, the extinction's also without
    ``per_point``: one point, the world's).  The emission grid (shape + (3,), W/(m^3 sr))
    sums the field emission terms."""
    density = np.asarray(base, np.float32)
    if co.density_field is not None:
        f = np.maximum(np.nan_to_num(np.asarray(sample(co.density_field), np.float64)), 0.0)
        density = (density * f).astype(np.float32)
    out = dataclasses.replace(co, density_field=None, colour_means=[],
                              emission_terms=[t for t in co.emission_terms
                                              if not isinstance(t, FIELD_TERMS)])
    scatter = extinction = None
    if co.colour_means:
        out, scatter, density, extinction = _colour_fields(co, out, density, sample, grid_of,
                                                           per_point)
    grid = None
    for t in co.emission_terms:
        if isinstance(t, FIELD_TERMS):
            per = t.per_voxel(sample, grid_of)
            per = np.broadcast_to(per, density.shape + (3,))
            grid = per.astype(np.float32) if grid is None else grid + per
    return Realised(density, out, grid, scatter, extinction)


def _per_point(values, shape) -> np.ndarray:
    """float64 (N, 3) of a colour's ``values`` at the lattice points of ``shape``: RGB, a
    value per point (grey), or per point an RGB (NaN and inf read as 0)."""
    v = np.nan_to_num(np.asarray(values, np.float64), posinf=0.0, neginf=0.0)
    if v.shape == tuple(shape):   # a value into a colour: grey
        v = v[..., None]
    return np.broadcast_to(v, tuple(shape) + (3,)).reshape(-1, 3)


def _colour_fields(co: VolumeCoefficients, out: VolumeCoefficients, density, sample, grid_of,
                   per_point: bool = True):
    """(``out`` with the colour fields' mean coefficients and anisotropy added, the scatter
    grid or None, the density, the extinction grid or None) for ``realise``.  Where the
    colours change the extinction, its grey part per point (the least-squares scale k of the
    mean extinction's colour) goes into the density, so an extinction that varies in
    brightness only (a grey colour field into Volume Scatter or Volume Absorption, a grey
    Absorption Color field) needs no more; what is left (a change of its colour beyond
    ``EXTINCTION_SPREAD``) is each point's factor per channel on the mean extinction (with
    ``per_point``)."""
    n = density.size
    d = density.reshape(-1).astype(np.float64)
    ss = np.broadcast_to(out.sigma_s, (n, 3)).astype(np.float64)
    sa = np.broadcast_to(out.sigma_a, (n, 3)).astype(np.float64)
    sw = float(np.mean(out.sigma_s))
    g_sum = out.g * sw
    for m in co.colour_means:
        colours = dict(m.consts)
        for name, f in m.fields.items():
            colours[name] = _per_point(sample(f), density.shape)
        for name, attr in m.attributes.items():
            grid = grid_of(attr)
            if grid is not None:
                colours[name] = colours[name] * _per_point(grid, density.shape)
        ssm, sam = m.build(colours)
        ssm = m.weight * np.maximum(np.broadcast_to(ssm, (n, 3)), 0.0)
        ss += ssm
        sa += m.weight * np.maximum(np.broadcast_to(sam, (n, 3)), 0.0)
        s = float(np.mean(weighted_mean(ssm, d)))
        g_sum += s * m.g
        sw += s
    out.g = g_sum / sw if sw > 0.0 else out.g
    st = ss + sa
    ref = weighted_mean(st, d)
    norm = float(ref @ ref)
    k = np.maximum(st @ ref / norm, 0.0) if norm > 0.0 else np.ones(n)
    if np.all(np.abs(k - 1.0) <= 1e-6):
        k = np.ones(n)
    else:   # the extinction's brightness per point into the density
        density = (d * k).reshape(density.shape).astype(np.float32)
    per = np.where(k > 0.0, 1.0 / np.where(k > 0.0, k, 1.0), 0.0)[:, None]
    ss, sa = ss * per, sa * per
    weights = d * k
    out.sigma_s, out.sigma_a = weighted_mean(ss, weights), weighted_mean(sa, weights)
    extinction = None
    mean_st = out.sigma_s + out.sigma_a
    st = ss + sa
    lit = weights > 0
    if per_point and np.any(lit) and np.max(np.abs(st[lit] - mean_st)) > EXTINCTION_SPREAD * max(
            float(np.max(mean_st)), 1e-30):
        per = np.where(mean_st > 0.0, st / np.where(mean_st > 0.0, mean_st, 1.0), 1.0)
        extinction = per.reshape(density.shape + (3,)).astype(np.float32)
    mean = np.where(out.sigma_s > 0.0, out.sigma_s, 1.0)
    factor = np.where(out.sigma_s > 0.0, ss / mean, 1.0)
    if np.all(np.abs(factor - 1.0) <= 1e-6):
        return out, None, density, extinction
    return out, factor.reshape(density.shape + (3,)).astype(np.float32), density, extinction
