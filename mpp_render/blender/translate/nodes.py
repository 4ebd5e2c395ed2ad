"""Walking shader node trees: which closures reach an output socket, and with what inputs.

An input resolves to one of three kinds: a *constant* (unlinked socket values, RGB and Value
nodes, links through Reroute nodes, node groups and muted nodes), an *attribute* (an
Attribute node linked straight in, reported by name: the caller may map it to a VDB grid),
or a *field*: any other node tree (textures, math, colour ramps, ...), copied by
``shadergraph.build`` into a plain graph the caller evaluates where it needs the values (a
medium's voxels).  A field that reads nothing of the point (a Math node on constants) is
constant; nodes a field cannot evaluate are listed in it and replaced by their input's value.

Objects returned here hold Blender nodes: use them only while the depsgraph is alive.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

from .convert import scalar

GROUP_INPUT = "NodeGroupInput"
GROUP_OUTPUT = "NodeGroupOutput"
GROUP = "ShaderNodeGroup"
REROUTE = "NodeReroute"
MIX_SHADER = "ShaderNodeMixShader"
ADD_SHADER = "ShaderNodeAddShader"
CONSTANT_NODES = ("ShaderNodeRGB", "ShaderNodeValue")
ATTRIBUTE_NODE = "ShaderNodeAttribute"
MAX_DEPTH = 64  # guards against pathological (recursive) group nesting

Stack = Tuple  # the group nodes entered so far, innermost last


@dataclass
class Closure:
    """A shader node whose output reaches the walked socket.

    ``weight``: product of the Mix Shader factors on the way (dimensionless).  ``stack``: the
    group nodes the node sits in, needed to resolve its linked inputs."""

    node: object
    weight: float
    stack: Stack = ()


@dataclass
class Resolved:
    """What feeds one input socket.

    Exactly one of: ``value`` (a constant float or tuple), ``attribute`` (name of the
    geometry attribute an Attribute node reads; ``output`` names its socket), or ``field``
    (a ``shadergraph.Field``: the node tree linked in; it may turn out constant,
    ``field.varies`` False).  ``unsupported``: the node that makes the input non-constant
    when no field could be built."""

    value: object = None
    attribute: Optional[str] = None
    output: Optional[str] = None
    unsupported: object = None
    field: object = None


def link_into(socket):
    """The enabled link feeding an input socket, or None."""
    if not socket.is_linked:
        return None
    for link in socket.links:
        if link.is_valid and not link.is_muted:
            return link
    return None


def _group_output(tree):
    """The active Group Output node of a node group's tree, or None."""
    outputs = [n for n in tree.nodes if n.bl_idname == GROUP_OUTPUT]
    for n in outputs:
        if n.is_active_output:
            return n
    return outputs[0] if outputs else None


def _input_by_identifier(node, identifier):
    for s in node.inputs:
        if s.identifier == identifier:
            return s
    return None


def _through_muted(node, out_socket):
    """The input socket a muted node passes ``out_socket`` through from, or None."""
    for link in node.internal_links:
        if link.to_socket.identifier == out_socket.identifier:
            return link.from_socket
    return None


def upstream(node, out_socket, stack):
    """Follow pass-through nodes (reroute, groups, muted nodes) back from ``out_socket``.

    Returns ``(input_socket, stack)`` to continue from, or None when ``node`` is a real
    producer (or a dead end: ``(None, stack)``)."""
    if node.mute:
        return _through_muted(node, out_socket), stack
    kind = node.bl_idname
    if kind == REROUTE:
        return node.inputs[0], stack
    if kind == GROUP:
        tree = node.node_tree
        out = _group_output(tree) if tree is not None else None
        if out is None:
            return None, stack
        return _input_by_identifier(out, out_socket.identifier), stack + (node,)
    if kind == GROUP_INPUT:
        if not stack:
            return None, stack
        return _input_by_identifier(stack[-1], out_socket.identifier), stack[:-1]
    return None


def closures(socket, weight: float = 1.0, stack: Stack = (), on_unsupported=None,
             _depth: int = 0) -> List[Closure]:
    """Closures reaching the shader input ``socket`` (e.g. a Material Output's 'Volume').

    Follows Add Shader, Mix Shader (constant factor, clamped to [0, 1]), Reroute, node groups
    and muted nodes.  Every other node linked in is returned as a :class:`Closure`; the
    caller decides whether it knows it.  ``on_unsupported(mix_node, resolved)`` is called when
    a Mix Shader factor is not constant (its socket value is used instead)."""
    if socket is None or weight == 0.0 or _depth > MAX_DEPTH:
        return []
    link = link_into(socket)
    if link is None:
        return []
    node, out_socket = link.from_node, link.from_socket
    nxt = upstream(node, out_socket, stack)
    if nxt is not None:
        sock, inner = nxt
        return closures(sock, weight, inner, on_unsupported, _depth + 1)
    kind = node.bl_idname
    if kind == ADD_SHADER:
        return (closures(node.inputs[0], weight, stack, on_unsupported, _depth + 1)
                + closures(node.inputs[1], weight, stack, on_unsupported, _depth + 1))
    if kind == MIX_SHADER:
        res = resolve(node.inputs[0], stack)
        fac = res.value
        if res.field is not None:
            if (res.field.varies or res.field.unsupported) and on_unsupported is not None:
                on_unsupported(node, res)
            if not res.field.varies:
                fac = res.field.constant()
        if fac is None:
            if on_unsupported is not None and res.field is None:
                on_unsupported(node, res)
            fac = node.inputs[0].default_value
        fac = min(max(scalar(fac), 0.0), 1.0)
        return (closures(node.inputs[1], weight * (1.0 - fac), stack, on_unsupported, _depth + 1)
                + closures(node.inputs[2], weight * fac, stack, on_unsupported, _depth + 1))
    return [Closure(node, weight, stack)]


def resolve(socket, stack: Stack = (), _depth: int = 0, _top=None) -> Resolved:
    """What feeds the (non-shader) input ``socket``: a constant, an attribute, or a field.
    See :class:`Resolved`."""
    top = _top if _top is not None else (socket, stack)
    link = link_into(socket) if _depth <= MAX_DEPTH else None
    if link is None:
        value = getattr(socket, "default_value", None)
        if value is not None and not isinstance(value, (int, float, str)):
            value = tuple(value)
        return Resolved(value=value)
    node, out_socket = link.from_node, link.from_socket
    nxt = upstream(node, out_socket, stack)
    if nxt is not None:
        sock, inner = nxt
        if sock is None:
            return Resolved(value=socket_value(out_socket))
        return resolve(sock, inner, _depth + 1, top)
    if node.bl_idname in CONSTANT_NODES:
        return Resolved(value=socket_value(out_socket))
    if node.bl_idname == ATTRIBUTE_NODE and getattr(node, "attribute_type", "GEOMETRY") \
            == "GEOMETRY":
        return Resolved(attribute=node.attribute_name, output=out_socket.name)
    from .shadergraph import build  # shadergraph walks links with the helpers above
    return Resolved(field=build(*top))


def socket_value(socket):
    """The value of an (output) socket as a float or a tuple."""
    value = getattr(socket, "default_value", 0.0)
    if isinstance(value, (int, float)):
        return float(value)
    return tuple(value)


def output_node(tree, target: str = "CYCLES"):
    """The active output node of a material, world or light node tree (or None)."""
    if tree is None:
        return None
    try:
        return tree.get_output_node(target)
    except (AttributeError, TypeError):
        return None


def describe(node) -> str:
    """``'Name' (bl_idname)`` of a node for messages."""
    return f"'{node.name}' ({node.bl_idname})"
