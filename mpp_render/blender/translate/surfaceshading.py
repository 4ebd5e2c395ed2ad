"""Surface shading of Blender materials (opaque meshes), reduced to scene.Surface fields:
the Principled BSDF as Cycles layers it, the Diffuse BSDF and Emission, weighted by their Mix
Shader factors (materials.output_closures)."""
from __future__ import annotations

from typing import List

import numpy as np

from .convert import rgb
from .materials import ClosureInputs, output_closures
from .nodes import describe

DEFAULT_SURFACE_COLOR = np.full(3, 0.8)   # Cycles' default surface: 0.8 grey diffuse


# Principled BSDF inputs read into scene.Surface (name in the node -> Surface field); the
# specular F0 and the emission are derived from several inputs
_PRINCIPLED_NUMBERS = {"Roughness": "roughness", "Metallic": "metallic",
                       "Coat Weight": "coat_weight", "Coat Roughness": "coat_roughness",
                       "Coat IOR": "coat_ior", "Diffuse Roughness": "diffuse_roughness"}
_PRINCIPLED_COLOURS = {"Base Color": "base_color", "Specular Tint": "specular_tint",
                       "Coat Tint": "coat_tint"}
# inputs whose effect we leave out: (name, value that means "off", what is lost)
_PRINCIPLED_IGNORED = (("Subsurface Weight", 0.0, "subsurface scattering (rendered as diffuse)"),
                       ("Transmission Weight", 0.0, "transmission (rendered opaque)"),
                       ("Sheen Weight", 0.0, "sheen"),
                       ("Alpha", 1.0, "transparency (rendered opaque)"),
                       ("Anisotropic", 0.0, "anisotropy (rendered isotropic)"),
                       ("Thin Film Thickness", 0.0, "thin-film iridescence"))


def principled_f0(ior: float, specular_ior_level: float) -> float:
    """F0 of the Principled BSDF's dielectric specular layer as Cycles adjusts it:
    ((IOR - 1) / (IOR + 1))^2 x 2 x Specular IOR Level, clamped to [0, 1]."""
    ior = max(float(ior), 1e-5)
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * max(float(specular_ior_level), 0.0)
    return float(min(max(f0, 0.0), 1.0))


def _principled(inp: ClosureInputs, where, warnings) -> dict:
    """The scene.Surface shading fields of one Principled BSDF node."""
    node = inp.closure.node
    out = {field: inp.number(name) for name, field in _PRINCIPLED_NUMBERS.items()}
    out.update({field: inp.color(name) for name, field in _PRINCIPLED_COLOURS.items()})
    out["specular"] = principled_f0(inp.number("IOR"), inp.number("Specular IOR Level"))
    out["emission"] = inp.color("Emission Color") * inp.number("Emission Strength")
    out["multiscatter"] = getattr(node, "distribution", "MULTI_GGX") == "MULTI_GGX"
    lost = [what for name, off, what in _PRINCIPLED_IGNORED
            if name in node.inputs and abs(inp.number(name) - off) > 1e-6]
    lost += [f"the linked '{name}'" for name in ("Normal", "Coat Normal", "Tangent")
             if name in node.inputs and node.inputs[name].is_linked]
    if lost:
        warnings.append(f"{where}: {describe(node)} uses {', '.join(lost)}, which the MPP "
                        "engine does not render; left out")
    return out


_DIFFUSE_DEFAULTS = {"specular": 0.0, "metallic": 0.0, "coat_weight": 0.0}


def surface_shading(material, where: str, warnings: List[str]) -> dict:
    """The scene.Surface shading fields of an opaque material, as keyword arguments:
    ``base_color``, ``emission`` (W/(m^2 sr)), ``specular`` (F0), ``roughness``,
    ``metallic``, ``specular_tint``, ``coat_*``, ``diffuse_roughness``, ``multiscatter`` and
    ``weight`` (see scene.Surface).

    A Principled BSDF gives all of them; a Diffuse BSDF is a base colour with no specular layer
    (its Roughness is the Oren-Nayar roughness); Emission shaders and the Principled emission
    add, weighted by their Mix Shader factors.  Several BSDFs mixed together become one with
    the weighted mean of their inputs (with a warning); ``weight`` is the BSDFs' total share.
    No material: Cycles' default 0.8 grey diffuse."""
    if material is None:
        return {"base_color": DEFAULT_SURFACE_COLOR.copy()}
    tree = getattr(material, "node_tree", None)
    if tree is None:
        return {"base_color": rgb(material.diffuse_color)}
    found = output_closures(tree, "Surface", where, warnings)
    emission = np.zeros(3)
    bsdfs = []
    if not found:
        warnings.append(f"{where}: no surface or volume shader is connected; rendered black")
    for c in found:
        inp = ClosureInputs(c, where, warnings)
        kind = c.node.bl_idname
        if kind == "ShaderNodeBsdfPrincipled":
            fields = _principled(inp, where, warnings)
            emission = emission + c.weight * fields.pop("emission")
            bsdfs.append((c.weight, fields))
        elif kind == "ShaderNodeBsdfDiffuse":
            bsdfs.append((c.weight, dict(_DIFFUSE_DEFAULTS, base_color=inp.color("Color"),
                                         diffuse_roughness=inp.number("Roughness"))))
        elif kind == "ShaderNodeEmission":
            emission = emission + c.weight * inp.color("Color") * inp.number("Strength")
        else:
            warnings.append(f"{where}: surface shader {describe(c.node)} is not supported; "
                            "ignored (black)")
    out = {"emission": emission}
    total = sum(w for w, _ in bsdfs)
    if not bsdfs or total <= 0.0:
        out.update(base_color=np.zeros(3), weight=0.0)
        return out
    if len(bsdfs) > 1:
        warnings.append(f"{where}: {len(bsdfs)} surface BSDFs are mixed; rendered as one "
                        "Principled BSDF with the weighted mean of their inputs")
    keys = set().union(*(f for _, f in bsdfs))
    for k in keys:
        vals = [(w, f[k]) for w, f in bsdfs if k in f]
        wsum = sum(w for w, _ in vals)
        if k == "multiscatter":
            out[k] = any(v for _, v in vals)
        else:
            out[k] = sum(w * np.asarray(v, np.float64) for w, v in vals) / wsum
            if np.ndim(out[k]) == 0:
                out[k] = float(out[k])
    out["weight"] = float(total)
    return out
