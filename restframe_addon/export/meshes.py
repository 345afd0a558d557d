"""Meshes: evaluated loop triangles, materials, corner normals and UVs read in bulk, placed per instance.

Positions, corner vertices and material indices are read from their attributes, whose
``foreach_get`` copies contiguous storage; the same values through ``mesh.vertices``,
``mesh.loops`` or the loop triangles' ``vertices``/``material_index`` go element by element
(261k triangles: 1 ms against 20-120 ms each).  Only the triangles' corners have no such path.
"""

from __future__ import annotations

import numpy as np

from .errors import ExportCancelled
from .keyed_speed import is_finite
from .materials import MaterialExporter


class MeshData:
    """One evaluated mesh in its object space, ready to be placed per instance."""

    __slots__ = ("vertices", "triangles", "materials", "normals", "uvs")

    def __init__(self, vertices, triangles, materials, normals, uvs):
        self.vertices, self.triangles, self.materials = vertices, triangles, materials
        self.normals, self.uvs = normals, uvs


def read_mesh(obj, mesh, materials: MaterialExporter, should_stop=lambda: False) -> MeshData | None:
    """Vertices, loop triangles, global material indices, corner normals and UVs.

    ``should_stop`` is checked between the bulk reads (a million triangles take seconds).
    """

    def check():
        if should_stop():
            raise ExportCancelled()

    tris = mesh.loop_triangles
    n_tri, n_vert = len(tris), len(mesh.vertices)
    if n_tri == 0 or n_vert == 0:
        return None
    check()
    vertices = np.empty(n_vert * 3, dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", vertices)
    check()
    corners = np.empty(n_tri * 3, dtype=np.int32)
    tris.foreach_get("loops", corners)
    corner_vertex = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.attributes[".corner_vert"].data.foreach_get("value", corner_vertex)
    triangles = corner_vertex[corners]
    check()
    slot_of_tri = np.zeros(n_tri, dtype=np.int32)
    material_index = mesh.attributes.get("material_index")  # absent while every face uses the first slot
    if material_index is not None:
        face_of_tri = np.empty(n_tri, dtype=np.int32)
        mesh.loop_triangle_polygons.foreach_get("value", face_of_tri)
        slot_of_face = np.empty(len(mesh.polygons), dtype=np.int32)
        material_index.data.foreach_get("value", slot_of_face)
        slot_of_tri = slot_of_face[face_of_tri]

    slots = [slot.material for slot in obj.material_slots] or [None]
    lookup = np.array([materials.index_of(m) for m in slots], dtype=np.int32)
    global_materials = lookup[np.clip(slot_of_tri, 0, len(lookup) - 1)]

    normals = None
    check()
    if mesh.normals_domain != 'FACE':  # flat meshes: the tracer's geometric normals are exact
        corner_normals = np.empty(len(mesh.loops) * 3, dtype=np.float32)
        check()
        mesh.corner_normals.foreach_get("vector", corner_normals)
        check()
        normals = corner_normals.reshape(-1, 3)[corners].reshape(n_tri, 3, 3).astype(np.float64)

    uvs = None
    layer = next((uv for uv in mesh.uv_layers if uv.active_render), None)
    if layer is not None and any(_reads_uvs(materials.materials[i]) for i in np.unique(lookup)):
        corner_uvs = np.empty(len(mesh.loops) * 2, dtype=np.float32)
        layer.uv.foreach_get("vector", corner_uvs)
        uvs = corner_uvs.reshape(-1, 2)[corners].reshape(n_tri, 3, 2).astype(np.float64)
        for index, affine in materials.uv_transforms.items():  # Mapping nodes, UDIM layouts
            sel = global_materials == index
            if np.any(sel):
                uvs[sel] = uvs[sel] @ affine[:, :2].T + affine[:, 2]

    check()
    vertices = vertices.reshape(-1, 3).astype(np.float64)
    vertices[~is_finite(vertices)] = np.inf  # Blender keeps an inf as 3.4e38: the core skips such triangles
    return MeshData(vertices, triangles.reshape(-1, 3),
                     global_materials, normals, uvs)


def _reads_uvs(material) -> bool:
    """Whether a material looks an image up through the UVs."""
    return any(t is not None for t in (material.base_color_texture, material.alpha_texture, material.normal_texture))


def place(data: MeshData, matrix: np.ndarray):
    """World-space vertices and normals for one instance transform."""
    linear, offset = matrix[:3, :3], matrix[:3, 3]
    with np.errstate(invalid="ignore"):  # non-finite vertices stay non-finite: the core skips them
        vertices = data.vertices @ linear.T + offset
    normals = None
    if data.normals is not None:
        # normals transform with the inverse transpose; row vectors: n @ inv(linear)
        normals = data.normals @ np.linalg.inv(linear)
        normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-300)
    return vertices, normals
