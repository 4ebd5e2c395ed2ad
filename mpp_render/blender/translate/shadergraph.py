"""Shader node trees that feed an input socket, copied into plain graphs
(``mpp_render.textures.graph``) and evaluated at a medium's voxels.

``build(socket, stack)`` follows the links into ``socket`` back through the tree: Reroute
nodes, node groups (flattened: a node inside a group gets the id '<group node>/.../<node>')
and muted nodes (their internal links) are passed through, inserting a conversion where a
socket on the way has another type (Blender converts at every link).  Each node the graph
can evaluate becomes a ``graph.Node`` with its settings (every RNA property of its own: enum,
bool, int, float, string; a Color Ramp's elements; a Texture Coordinate's Object as that
object's world -> object matrix) and its inputs (the socket values as they are in the
evaluated tree, so drivers and keyframes are in them); an unlinked texture Vector is left out
(the texture reads the Generated coordinates, as in Blender).  A node the graph cannot
evaluate is *unsupported*: the input it feeds takes that input's own value and the node is
listed (``Field.messages``), so the nodes around it still work.  The result is a
:class:`Field`; its ``key`` hashes the whole description, so an unchanged tree keeps its key
across frames and an animated value changes it.

:class:`FieldContext` evaluates fields at the points of a voxel lattice of one object
(``sampler``), keeping results in a cache under the field's key, the lattice and -- only when
the field reads world positions -- the object's matrix.

Objects here hold no Blender data once built.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable, Dict, FrozenSet, List, Optional, Tuple

import numpy as np

from ...cache import digest
from ...textures import graph as g
from .convert import LUMINANCE, fmt, matrix
from .nodes import MAX_DEPTH, link_into, socket_value, upstream, describe

NUMERIC = {"VALUE": g.VALUE, "INT": g.VALUE, "BOOLEAN": g.VALUE, "VECTOR": g.VECTOR,
           "RGBA": g.RGBA}


@dataclass
class Unsupported:
    """A node replaced by the value of the input it feeds: ``node`` and ``reason`` for
    messages, ``into`` ('input' of 'consumer'), ``value`` used instead."""

    node: str
    reason: str
    into: str
    value: object


@dataclass
class Field:
    """What a node tree gives one input: ``graph`` evaluated at ``output`` (a Link, or a
    constant when nothing evaluable is linked), converted to ``type`` (the input socket's:
    VALUE, VECTOR or RGBA).  ``socket``/``consumer``: the input and its node (messages);
    ``nodes``: the names of the nodes evaluated; ``unsupported``: the nodes replaced by their
    input's value; ``reads``: what of the points it reads (empty: the same everywhere);
    ``key``: hash of all of it."""

    graph: g.Graph
    output: g.Input
    type: str
    socket: str = ""
    consumer: str = ""
    nodes: Tuple[str, ...] = ()
    unsupported: List[Unsupported] = field(default_factory=list)
    reads: FrozenSet[str] = frozenset()
    key: str = ""
    notes: List[str] = field(default_factory=list)

    @property
    def varies(self) -> bool:
        return bool(self.reads)

    def attributes(self) -> List[str]:
        return sorted(r.split(":", 1)[1] for r in self.reads if r.startswith("attribute:"))

    def constant(self):
        """The value of a field that does not vary: a float (VALUE) or an RGB/XYZ tuple."""
        v = g.evaluate(self.graph, self.output, g.Points(np.zeros((1, 3))), self.type)[0]
        return float(v) if self.type == g.VALUE else tuple(float(x) for x in v)

    def at(self, points: g.Points) -> np.ndarray:
        return g.evaluate(self.graph, self.output, points, self.type)

    def describe(self) -> str:
        """``'Density' of 'Principled Volume' (driven by 'Noise Texture', 'Math')``."""
        names = ", ".join(f"'{n}'" for n in self.nodes[:4]) + (", ..." if len(self.nodes) > 4
                                                                 else "")
        return f"'{self.socket}' of {self.consumer}" + (f" (driven by {names})" if names else "")

    def messages(self, where: str) -> List[str]:
        """One warning per unsupported node (and per setting left out)."""
        return [f"{where}: node {u.node} linked into {u.into} {u.reason}; using the input's "
                f"value {fmt(u.value)}" for u in self.unsupported] \
            + [f"{where}: {note}" for note in self.notes]


# -- building -------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def _base_properties() -> FrozenSet[str]:
    import bpy
    return frozenset(bpy.types.ShaderNode.bl_rna.properties.keys())


def _plain(v):
    """An RNA value as plain data (enum flags as a sorted tuple)."""
    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, (set, frozenset)):
        return tuple(sorted(str(x) for x in v))
    try:
        return tuple(_plain(x) for x in v)
    except TypeError:
        return str(v)


def _constant(socket):
    """A socket's own value in the graph's terms, or None when it is not numeric."""
    kind = NUMERIC.get(socket.type)
    value = getattr(socket, "default_value", None)
    if kind is None or value is None:
        return None
    if kind == g.VALUE:
        return float(value)
    v = tuple(float(x) for x in value)
    if kind == g.VECTOR:
        return (v + (0.0, 0.0, 0.0))[:3]
    return (v + (1.0,))[:4] if len(v) == 3 else v[:4]


def _convert_constant(value, to: str):
    kind = g.type_of(value)
    if kind == to or to not in (g.VALUE, g.VECTOR, g.RGBA):
        return value
    if to == g.VALUE:
        return float(np.asarray(value[:3]) @ LUMINANCE) if kind == g.RGBA else float(np.mean(value))
    v = (float(value),) * 3 if kind == g.VALUE else tuple(value[:3])
    return v + (1.0,) if to == g.RGBA else v


def _props(node) -> dict:
    """The settings of ``node`` that change its values (see the module docstring)."""
    base = _base_properties()
    out = {}
    for p in node.bl_rna.properties:
        name = p.identifier
        if name in base or p.type in ("POINTER", "COLLECTION") or name.startswith("bl_"):
            continue
        try:
            out[name] = _plain(getattr(node, name))
        except AttributeError:
            continue
    kind = node.bl_idname
    if kind == "ShaderNodeValToRGB":
        ramp = node.color_ramp
        out["elements"] = tuple((float(e.position), tuple(float(c) for c in e.color))
                                for e in ramp.elements)
        out["interpolation"] = ramp.interpolation
        out["color_mode"] = ramp.color_mode
        out["hue_interpolation"] = ramp.hue_interpolation
    elif kind == "ShaderNodeValue":
        out["value"] = float(node.outputs[0].default_value)
    elif kind == "ShaderNodeRGB":
        out["color"] = tuple(float(c) for c in node.outputs[0].default_value)
    elif kind == "ShaderNodeTexCoord":
        ob = getattr(node, "object", None)
        if ob is not None:
            out["object_matrix"] = tuple(np.linalg.inv(matrix(ob.matrix_world)).ravel().tolist())
    return out


def _mapping_note(node) -> Optional[str]:
    """Why a texture node's own mapping panel (Texture Mapping) is not the identity."""
    tm = getattr(node, "texture_mapping", None)
    if tm is None:
        return None
    identity = (tuple(tm.translation) == (0, 0, 0) and tuple(tm.rotation) == (0, 0, 0)
                and tuple(tm.scale) == (1, 1, 1) and not tm.use_min and not tm.use_max
                and (tm.mapping_x, tm.mapping_y, tm.mapping_z) == ("X", "Y", "Z"))
    return None if identity else "has a texture mapping of its own, which is ignored"


@dataclass
class _Dead:
    """A producer the graph cannot evaluate: ``node`` and why."""

    node: object
    reason: str


_OWN = object()  # nothing reaches the input (a dangling reroute): it keeps its own value


class _Builder:
    def __init__(self):
        self.graph = g.Graph()
        self.unsupported: List[Unsupported] = []
        self.notes: List[str] = []
        self.types: Dict[g.Link, str] = {}

    def input(self, socket, node, stack, depth):
        """The value of input ``socket`` of ``node``: a constant, a Link, or None to leave it
        out (an unlinked texture Vector)."""
        link = link_into(socket) if depth <= MAX_DEPTH else None
        own = _constant(socket)
        if link is None:
            if socket.identifier == "Vector" and node.bl_idname.startswith("ShaderNodeTex") \
                    and getattr(socket, "hide_value", False):
                return None
            return own
        got = self.source(link.from_node, link.from_socket, stack, depth + 1)
        if got is _OWN:
            return own
        if isinstance(got, _Dead):
            value = own if own is not None else 0.0
            self.unsupported.append(Unsupported(describe(got.node), got.reason,
                                                f"'{socket.name}' of {describe(node)}", value))
            return value
        return got

    def source(self, node, out_socket, stack, depth):
        """What the output ``out_socket`` of ``node`` gives: a Link, a constant, a
        :class:`_Dead` end, or ``_OWN``."""
        if depth > MAX_DEPTH:
            return _Dead(node, "is nested too deeply")
        nxt = upstream(node, out_socket, stack)
        if nxt is not None:  # reroute, group, group input, muted node
            sock, inner = nxt
            if sock is None:
                return socket_value(out_socket)
            owner = sock.node
            got = self.input(sock, owner, inner, depth + 1)
            if got is None:
                return _OWN
            if isinstance(got, _Dead):
                return got
            return self._as(got, NUMERIC.get(out_socket.type))
        key = "/".join([s.name for s in stack] + [node.name])
        desc = g.Node(node.bl_idname, _props(node), {}, node.name)
        why = g.unsupported(desc, out_socket.identifier)
        if why is not None:
            return _Dead(node, why)
        if key not in self.graph.nodes:
            self.graph.nodes[key] = desc
            note = _mapping_note(node)
            if note:
                self.notes.append(f"node {describe(node)} {note}")
            for s in node.inputs:
                if not s.enabled or s.type not in NUMERIC:
                    continue
                v = self.input(s, node, stack, depth + 1)
                if v is not None:
                    desc.inputs[s.identifier] = v
        link = g.Link(key, out_socket.identifier)
        self.types[link] = NUMERIC.get(out_socket.type, g.VALUE)
        return link

    def _as(self, value, to):
        """``value`` passed on through a socket of type ``to`` (a conversion where needed)."""
        if to is None:
            return value
        if not isinstance(value, g.Link):
            return _convert_constant(value, to)
        if self.types.get(value, to) == to:
            return value
        key = f"{value.node}>{value.socket}>{to}"
        self.graph.nodes.setdefault(key, g.Node(g.CONVERT, {"to": to}, {"Value": value},
                                                "conversion"))
        link = g.Link(key, "Value")
        self.types[link] = to
        return link


def build(socket, stack=()) -> Optional[Field]:
    """The :class:`Field` feeding input ``socket`` (of a node inside the groups ``stack``),
    or None when nothing is linked into it."""
    if link_into(socket) is None:
        return None
    b = _Builder()
    consumer = socket.node
    out = b.input(socket, consumer, stack, 0)
    kind = NUMERIC.get(socket.type, g.VALUE)
    if out is None:
        out = _constant(socket)
    reads = frozenset(g.reads(b.graph, out))
    names = tuple(n.name for n in b.graph.nodes.values() if n.kind != g.CONVERT)
    f = Field(b.graph, out, kind, socket.name, describe(consumer), names, b.unsupported, reads,
              notes=b.notes)
    f.key = digest(b.graph, out, kind)
    return f


# -- evaluating on a lattice ----------------------------------------------------------------

GridOf = Callable[[str], Optional[np.ndarray]]


@dataclass
class FieldContext:
    """What an object's fields are evaluated with: ``texspace`` (lo, hi) object-space box
    that Generated maps to [0, 1]^3 (None: Generated is the object coordinates), ``frame``,
    and ``store`` (a dict-like cache, e.g. ``CACHE.store('voxels')``, or None)."""

    texspace: Optional[Tuple[np.ndarray, np.ndarray]] = None
    frame: float = 0.0
    store: object = None

    def sampler(self, shape, index_to_object, world_matrix, grid_of: Optional[GridOf] = None,
                grids_key=None) -> "Sampler":
        """A :class:`Sampler` for the lattice ``shape`` whose index (i, j, k) lies at
        ``world_matrix @ index_to_object @ (i, j, k, 1)``.  ``grid_of(name)``: a grid's
        values on this lattice or None; ``grids_key``: a key of those grids' content (None:
        results reading grids are not kept in the store)."""
        return Sampler(self, tuple(int(s) for s in shape), np.asarray(index_to_object, np.float64),
                       np.asarray(world_matrix, np.float64), grid_of or (lambda name: None),
                       grids_key)


class Sampler:
    """Fields at the points of one lattice: ``sampler(field)`` -> float32 ``shape`` (VALUE)
    or ``shape + (3,)`` (VECTOR, RGBA); each field evaluated once."""

    def __init__(self, ctx: FieldContext, shape, index_to_object, world_matrix, grid_of,
                 grids_key):
        self.ctx, self.shape, self.i2o, self.world = ctx, shape, index_to_object, world_matrix
        self.grid_of, self.grids_key = grid_of, grids_key
        self._done: Dict[str, np.ndarray] = {}

    def _key(self, f: Field):
        if self.ctx.store is None or (f.attributes() and self.grids_key is None):
            return None
        world = self.world if "position" in f.reads else None
        grids = self.grids_key if f.attributes() else None
        tex = None if self.ctx.texspace is None else tuple(np.asarray(v, np.float64)
                                                          for v in self.ctx.texspace)
        return ("field", digest(f.key, self.shape, self.i2o, world, tex, grids))

    def __call__(self, f: Field) -> np.ndarray:
        if f.key in self._done:
            return self._done[f.key]
        key = self._key(f)
        values = self.ctx.store.get(key) if key is not None else None
        if values is None:
            attrs = {}
            for name in f.attributes():
                grid = self.grid_of(name)
                if grid is not None:
                    attrs[name] = grid
            values = g.evaluate_lattice(
                f.graph, f.output, f.type, self.shape, self.world @ self.i2o,
                world_to_object=np.linalg.pinv(self.world), texspace=self.ctx.texspace,
                attributes=attrs, frame=self.ctx.frame)
            if key is not None:
                self.ctx.store[key] = values
        self._done[f.key] = values
        return values


def points_sampler(positions):
    """A sampler of fields at world points ``positions`` (N,3) (the world volume's convention:
    object and generated coordinates are the position): float32 (N,) or (N, 3)."""
    pts = g.Points(np.asarray(positions, np.float64).reshape(-1, 3))

    def sample(f: Field) -> np.ndarray:
        return f.at(pts).astype(np.float32)
    return sample


def point_sampler(position, warn: Optional[Callable[[Field], None]] = None):
    """A sampler of fields at one world point (the world volume: object and generated
    coordinates are the position there, as Cycles' background): float32 (1,) or (1, 3).
    ``warn(field)`` is called for each field that varies in space."""
    pts = g.Points(np.asarray(position, np.float64).reshape(1, 3))

    def sample(f: Field) -> np.ndarray:
        if f.varies and warn is not None:
            warn(f)
        return f.at(pts).astype(np.float32)
    return sample
