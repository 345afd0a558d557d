"""Blender features a scene may use that RESTframe does not render yet, one question each.

Each ``uses_*`` function says whether an object (or material, or scene) uses one feature, so
the exporter can warn once per render and feature, naming the objects, and so a later
implementation can ask the same question to switch the feature on.  ``UNSUPPORTED`` holds
the warning text of each feature, in one place.
"""

from __future__ import annotations

from .materials import output_node, upstream

# feature -> what RESTframe does instead (the warning's second half)
UNSUPPORTED = {
    "holdout": "Holdout is not supported yet: rendered as an ordinary surface",
    "indirect only": "Indirect Only is not supported yet: rendered as directly visible",
    "ray visibility": "ray visibility (Visible to Camera / Diffuse / Glossy / Transmission / Shadow) "
                      "is not supported yet: seen by every ray",
    "shadow catcher": "Shadow Catcher is not supported: rendered as an ordinary surface",
    "alpha": "Principled Alpha (cut-outs, transparency) is not supported yet: rendered opaque",
    "normal map": "normal, bump and displacement maps are not supported yet: the mesh's own normals are used",
    "volume": "volumes are not supported: volume shaders and Volume objects are left out "
              "(a volume-only material renders black)",
    "hair": "hair strands (particle hair, Curves objects) are not supported: left out",
    "stereo": "Stereoscopy / multi-view is not supported yet: every view renders the same single camera",
}


def _bsdf_input(material, name):
    """The input ``name`` of the Principled BSDF on the material's Surface output, or None."""
    output = output_node(material) if material is not None else None
    node = upstream(output.inputs["Surface"]) if output is not None else None
    if node is None or node.type != 'BSDF_PRINCIPLED' or name not in node.inputs:
        return None
    return node.inputs[name]


def uses_holdout(obj, view_layer) -> bool:
    """Object or collection Holdout, or a Holdout shader on the Surface of one of its materials."""
    original = obj.original
    if original.is_holdout or (view_layer is not None and original.holdout_get(view_layer=view_layer)):
        return True
    return any(_surface_type(slot.material) == 'HOLDOUT' for slot in obj.material_slots)


def uses_indirect_only(obj, view_layer) -> bool:
    return view_layer is not None and obj.original.indirect_only_get(view_layer=view_layer)


def uses_ray_visibility(obj) -> bool:
    """Any of the Visibility panel's ray types switched off."""
    return not all(getattr(obj, name, True) for name in (
        "visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission", "visible_shadow"))


def uses_shadow_catcher(obj) -> bool:
    return bool(getattr(obj, "is_shadow_catcher", False))


def uses_alpha(material) -> bool:
    """A Principled Alpha below 1 or driven by a link (an image's alpha, a mask)."""
    alpha = _bsdf_input(material, "Alpha")
    return alpha is not None and (upstream(alpha) is not None or float(alpha.default_value) < 1.0)


def uses_normal_map(material) -> bool:
    """A link into the Principled Normal or Coat Normal, or into the output's Displacement."""
    output = output_node(material) if material is not None else None
    if output is not None and "Displacement" in output.inputs and upstream(output.inputs["Displacement"]) is not None:
        return True
    return any(socket is not None and upstream(socket) is not None
               for socket in (_bsdf_input(material, "Normal"), _bsdf_input(material, "Coat Normal")))


def uses_volume(material) -> bool:
    """Something linked into the material output's Volume."""
    output = output_node(material) if material is not None else None
    return output is not None and upstream(output.inputs["Volume"]) is not None


def uses_hair(obj) -> bool:
    """Particle hair rendered as strands, or a Curves (hair) object."""
    if obj.type == 'CURVES':
        return True
    return any(system.settings.type == 'HAIR' and system.settings.render_type == 'PATH'
               for system in getattr(obj, "particle_systems", ()))


def uses_stereo(scene) -> bool:
    return bool(scene.render.use_multiview)


def _surface_type(material):
    output = output_node(material) if material is not None else None
    node = upstream(output.inputs["Surface"]) if output is not None else None
    return node.type if node is not None else None


def object_features(obj, view_layer) -> list[str]:
    """The unsupported features (keys of ``UNSUPPORTED``) an evaluated object uses."""
    found = []
    checks = (("holdout", lambda: uses_holdout(obj, view_layer)),
              ("indirect only", lambda: uses_indirect_only(obj, view_layer)),
              ("ray visibility", lambda: uses_ray_visibility(obj)),
              ("shadow catcher", lambda: uses_shadow_catcher(obj)),
              ("hair", lambda: uses_hair(obj)),
              ("volume", lambda: obj.type == 'VOLUME'))
    for feature, used in checks:
        if used():
            found.append(feature)
    materials = [slot.material for slot in getattr(obj, "material_slots", ()) if slot.material is not None]
    for feature, used in (("alpha", uses_alpha), ("normal map", uses_normal_map), ("volume", uses_volume)):
        if feature not in found and any(used(m) for m in materials):
            found.append(feature)
    return found


class FeatureReport:
    """Collects which objects use which unsupported feature; one warning per feature at the end."""

    def __init__(self):
        self.users: dict[str, dict[str, None]] = {}  # feature -> names, in order of appearance

    def add(self, name: str, features: list[str]) -> None:
        for feature in features:
            self.users.setdefault(feature, {})[name] = None

    def warnings(self) -> list[str]:
        out = []
        for feature in UNSUPPORTED:
            names = list(self.users.get(feature, ()))
            if names:
                listed = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
                out.append(f"{listed}: {UNSUPPORTED[feature]}")
        return out
