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
    "shadow catcher": "Shadow Catcher is not supported: rendered as an ordinary surface",
    "bump map": "bump and displacement maps are not supported yet: the mesh's own normals are used",
    "volume": "volumes are not supported: volume shaders and Volume objects are left out "
              "(a volume-only material renders black)",
    "hair": "hair strands (particle hair, Curves objects) are not supported: left out",
}


def _bsdf_input(material, name):
    """The input ``name`` of the Principled BSDF on the material's Surface output, or None."""
    output = output_node(material) if material is not None else None
    node = upstream(output.inputs["Surface"]) if output is not None else None
    if node is None or node.type != 'BSDF_PRINCIPLED' or name not in node.inputs:
        return None
    return node.inputs[name]


def uses_shadow_catcher(obj) -> bool:
    return bool(getattr(obj, "is_shadow_catcher", False))


def uses_bump_map(material) -> bool:
    """A Bump node into the Principled Normal, a link into its Coat Normal, or into the output's
    Displacement (tangent-space Normal Map nodes are rendered, see surface_maps)."""
    output = output_node(material) if material is not None else None
    if output is not None and "Displacement" in output.inputs and upstream(output.inputs["Displacement"]) is not None:
        return True
    normal, coat = _bsdf_input(material, "Normal"), _bsdf_input(material, "Coat Normal")
    if coat is not None and upstream(coat) is not None:
        return True
    return normal is not None and upstream(normal) is not None and upstream(normal).type == 'BUMP'


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


def object_features(obj) -> list[str]:
    """The unsupported features (keys of ``UNSUPPORTED``) an evaluated object uses."""
    found = []
    checks = (("shadow catcher", lambda: uses_shadow_catcher(obj)),
              ("hair", lambda: uses_hair(obj)),
              ("volume", lambda: obj.type == 'VOLUME'))
    for feature, used in checks:
        if used():
            found.append(feature)
    materials = [slot.material for slot in getattr(obj, "material_slots", ()) if slot.material is not None]
    for feature, used in (("bump map", uses_bump_map), ("volume", uses_volume)):
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
