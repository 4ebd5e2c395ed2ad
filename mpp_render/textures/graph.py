"""Shader node trees as plain data, evaluated on arrays of points (no bpy).

The description
---------------
A :class:`Graph` holds :class:`Node` s by id.  A node is its ``kind`` (Blender's
``bl_idname``), its ``props`` (the settings that change its values: ``operation``,
``data_type``, ``blend_type``, ``use_clamp``, ``interpolation_type``, a Color Ramp's
``elements`` ((position, RGBA) pairs) and ``interpolation`` / ``color_mode`` /
``hue_interpolation``, ``noise_dimensions``, ``vector_type``, ...: plain strings, numbers,
booleans and tuples, named as the RNA properties are) and its ``inputs`` by socket
identifier: a constant (a float; a 3-tuple vector; a 4-tuple RGBA colour) or a :class:`Link`
to an output of another node (node id, output socket identifier).  An input left out takes
the node's default (for a texture's Vector: the Generated coordinates, as in Blender).  The
description holds every value the result depends on, so a content hash of it
(``mpp_render.cache.digest``) is a cache key.  The glue (``blender/translate/shadergraph.py``)
builds it from a Blender node tree, flattening groups, reroutes and muted nodes.

Points
------
:class:`Points` carries, for N points: ``position`` (N, 3) world metres (Geometry >
Position); ``object`` (N, 3) object-space coordinates (Texture Coordinate > Object);
``generated`` (N, 3) the position in the object's texture space, its bounding box mapped to
[0, 1]^3 (Texture Coordinate > Generated, and a texture's unlinked Vector: Cycles'
``NODE_TEXCO_VOLUME_GENERATED``); for the world volume both are the world position, as
Cycles' background shader has no object.  ``attributes``: name -> (N,) or (N, 3) values of
the grids at the points (the Attribute node, Volume Info's 'density', 'flame',
'temperature', 'color'); a name that is missing reads 0, as in Cycles.  ``frame``: the scene
frame (no shader node reads it; drivers and keyframes reach the description as socket
values).

Socket types, the conversions at a link: ``sockets.py``.  The node kinds, one function each:
``shadernodes.py`` (``KINDS``; ``unsupported`` says why a node cannot be evaluated, so the
glue can replace it by its input's value and warn).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Mapping, Optional, Set, Tuple, Union

import numpy as np

# the node kinds and socket types are part of the graph's API (re-exported)
from .shadernodes import CONVERT, KINDS, NodeKind, unsupported  # noqa: F401
from .sockets import (LUMINANCE, RGBA, VALUE, VECTOR, constant_array, convert,  # noqa: F401
                      type_of)

CHUNK = 1 << 17              # lattice points evaluated at once (bounds the temporaries)


@dataclass(frozen=True)
class Link:
    """Output ``socket`` (identifier) of node ``node`` (id in the graph)."""

    node: str
    socket: str


Constant = Union[float, Tuple[float, ...]]
Input = Union[Constant, Link]


@dataclass
class Node:
    """One node: ``kind`` (bl_idname), ``props`` (settings), ``inputs`` (identifier ->
    constant or Link), ``name`` (the node's name in Blender, for messages)."""

    kind: str
    props: Dict[str, Any] = field(default_factory=dict)
    inputs: Dict[str, Input] = field(default_factory=dict)
    name: str = ""


@dataclass
class Graph:
    nodes: Dict[str, Node] = field(default_factory=dict)


@dataclass
class Points:
    """Where a graph is evaluated (see the module docstring).  ``generated`` and ``object``
    default to ``position`` (the world volume's convention)."""

    position: np.ndarray
    generated: Optional[np.ndarray] = None
    object: Optional[np.ndarray] = None
    attributes: Mapping[str, np.ndarray] = field(default_factory=dict)
    frame: float = 0.0

    def __post_init__(self):
        self.position = np.asarray(self.position, np.float64).reshape(-1, 3)
        if self.generated is None:
            self.generated = self.position
        if self.object is None:
            self.object = self.position

    @property
    def n(self) -> int:
        return len(self.position)


# -- evaluation -----------------------------------------------------------------------------

class _Context:
    """One evaluation: the graph, the points and the outputs computed so far."""

    def __init__(self, graph: Graph, points: Points):
        self.graph, self.points, self.n = graph, points, points.n
        self._done: Dict[str, Outputs] = {}
        self._wanted: Dict[str, Set[str]] = {}
        for node in graph.nodes.values():
            for v in node.inputs.values():
                if isinstance(v, Link):
                    self._wanted.setdefault(v.node, set()).add(v.socket)

    def output(self, link: Link) -> Tuple[np.ndarray, str]:
        if link.node not in self._done:
            node = self.graph.nodes[link.node]
            self._done[link.node] = KINDS[node.kind].run(
                self, node, self._wanted.get(link.node, set()) | {link.socket})
        outs = self._done[link.node]
        if link.socket not in outs:
            raise KeyError(f"node '{self.graph.nodes[link.node].name}' has no output "
                           f"'{link.socket}'")
        return outs[link.socket]

    def raw(self, node: Node, ident: str, default) -> Tuple[np.ndarray, str]:
        v = node.inputs.get(ident, default)
        if isinstance(v, Link):
            return self.output(v)
        return constant_array(v, self.n)

    def value(self, node: Node, ident: str, default=0.0) -> np.ndarray:
        return convert(*self.raw(node, ident, default), VALUE)

    def vector(self, node: Node, ident: str, default=(0.0, 0.0, 0.0)) -> np.ndarray:
        return convert(*self.raw(node, ident, default), VECTOR)

    colour = vector

    def param(self, node: Node, ident: str, default=0.0):
        """A numeric input as a float when it is constant, else (N,) values (what the
        texture functions take)."""
        v = node.inputs.get(ident, default)
        if isinstance(v, Link):
            return self.value(node, ident, default)
        return float(convert(np.asarray(v, np.float64), type_of(v), VALUE))

    def texture_vector(self, node: Node) -> np.ndarray:
        """A texture's Vector: linked or set, else the Generated coordinates."""
        if "Vector" in node.inputs:
            return self.vector(node, "Vector")
        return np.asarray(self.points.generated, np.float64)


def evaluate_typed(graph: Graph, output: Input, points: Points) -> Tuple[np.ndarray, str]:
    """``(values, socket type)`` of ``output`` (a Link, or a constant) at ``points``."""
    if isinstance(output, Link):
        return _Context(graph, points).output(output)
    return constant_array(output, points.n)


def evaluate(graph: Graph, output: Input, points: Points, as_type: Optional[str] = None
             ) -> np.ndarray:
    """The values of ``output`` at ``points``: (N,) for a VALUE, (N, 3) for a VECTOR or RGBA
    output, converted to ``as_type`` when given (float64)."""
    values, kind = evaluate_typed(graph, output, points)
    return convert(values, kind, as_type) if as_type else values


def reads(graph: Graph, output: Input) -> Set[str]:
    """What of the points ``output`` depends on: 'position', 'generated', 'object',
    'attribute:<name>'.  Empty: the output is the same everywhere.  A node counts as
    reading all its inputs, whichever of its outputs is asked for."""
    found: Set[str] = set()
    seen: Set[Link] = set()
    todo = [output] if isinstance(output, Link) else []
    while todo:
        link = todo.pop()
        if link in seen:
            continue
        seen.add(link)
        node = graph.nodes[link.node]
        kind = KINDS.get(node.kind)
        if kind is not None and kind.reads is not None:
            found |= kind.reads(node, link.socket)
        for v in node.inputs.values():
            if isinstance(v, Link):
                todo.append(v)
    return found


def attributes_read(graph: Graph, output: Input) -> Set[str]:
    """The grid names ``output`` reads (Attribute and Volume Info nodes)."""
    return {r.split(":", 1)[1] for r in reads(graph, output) if r.startswith("attribute:")}


def evaluate_lattice(graph: Graph, output: Input, as_type: str, shape, index_to_world,
                     world_to_object=None, texspace=None,
                     attributes: Optional[Mapping[str, np.ndarray]] = None, frame: float = 0.0,
                     chunk: int = CHUNK) -> np.ndarray:
    """``output`` at the points of a voxel lattice: float32 of ``shape`` (VALUE) or
    ``shape + (3,)``.

    ``index_to_world``: 4x4 map of index (i, j, k) to world metres (voxel centres at integer
    indices); ``world_to_object``: 4x4 inverse of the object's world matrix (None: object
    coordinates are the world's); ``texspace``: ``(lo, hi)`` object-space box that
    Generated maps to [0, 1]^3 (None: Generated is the object coordinates);
    ``attributes``: name -> values at the lattice points (``shape`` or ``shape + (c,)``).
    Evaluated ``chunk`` points at a time."""
    shape = tuple(int(s) for s in shape)
    total = int(np.prod(shape))
    width = 1 if as_type == VALUE else 3
    out = np.empty((total, width), np.float32)
    i2w = np.asarray(index_to_world, np.float64)
    w2o = None if world_to_object is None else np.asarray(world_to_object, np.float64)
    if texspace is not None:
        lo = np.asarray(texspace[0], np.float64)
        size = np.asarray(texspace[1], np.float64) - lo
        size = np.where(size != 0.0, size, 1.0)
    flat = {name: np.asarray(a).reshape(total, -1) for name, a in (attributes or {}).items()}
    for start in range(0, total, max(int(chunk), 1)):
        stop = min(total, start + max(int(chunk), 1))
        ijk = np.stack(np.unravel_index(np.arange(start, stop), shape), axis=1).astype(np.float64)
        world = ijk @ i2w[:3, :3].T + i2w[:3, 3]
        obj = world if w2o is None else world @ w2o[:3, :3].T + w2o[:3, 3]
        gen = obj if texspace is None else (obj - lo) / size
        attrs = {name: (a[start:stop, 0] if a.shape[1] == 1 else a[start:stop])
                 for name, a in flat.items()}
        pts = Points(world, gen, obj, attrs, frame)
        out[start:stop] = evaluate(graph, output, pts, as_type).reshape(stop - start, width)
    return out.reshape(shape) if width == 1 else out.reshape(shape + (3,))
