"""Shader-node helpers shared by the material exporters."""

from __future__ import annotations

import bpy


def upstream_link(socket):
    """The link feeding a socket, through reroutes; None if unlinked (or muted)."""
    while socket is not None and socket.is_linked:
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None
        if link.from_node.type != 'REROUTE':
            return link
        socket = link.from_node.inputs[0]
    return None


def upstream(socket):
    """The node feeding a socket, through reroutes; None if unlinked."""
    link = upstream_link(socket)
    return link.from_node if link is not None else None


def output_node(id_data):
    """The active output node a path tracer uses, or None when nodes are off or missing."""
    tree = id_data.node_tree
    # use_nodes is always on from 5.0 (and deprecated there)
    if tree is None or (bpy.app.version < (5, 0, 0) and not id_data.use_nodes):
        return None
    return tree.get_output_node('CYCLES')
