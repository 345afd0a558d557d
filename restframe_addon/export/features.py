"""Blender features a scene may use that RESTframe does not render yet, one question each.

Each ``uses_*`` function says whether an object or material uses one feature, and
:func:`object_features`, :func:`lamp_features` and :func:`principled_features` list the features
an object, a lamp or a Principled node uses, so the exporter can warn once per render and feature
(:class:`FeatureReport`), naming the objects (materials as ``Material 'name'``), and so a later
implementation can ask the same question to switch the feature on.  ``UNSUPPORTED`` holds the
warning text of each feature, in one place.
"""

from __future__ import annotations

import math

from ..core.scene import RAY_DIFFUSE, RAY_GLOSSY, RAY_TRANSMISSION
from .nodes import output_node, upstream

# Principled BSDF inputs the renderer does not model (docs/physics.md), with the value that turns
# each off: set otherwise, or linked, the material is rendered without it and the render says so
# (a map on the Coat Normal is warned about with the other bump maps; Coat Tint: principled_features)
_WHITE = (1.0, 1.0, 1.0)
_NOT_MODELLED = (("Subsurface Weight", 0.0), ("Sheen Weight", 0.0), ("Anisotropic", 0.0), ("Specular Tint", _WHITE),
                 ("Thin Film Thickness", 0.0), ("Diffuse Roughness", 0.0))

# the lamp Ray Visibility bits whose closures a lamp's samples light all the same (Cycles: not lit)
_LAMP_RAY_VISIBILITY = ((RAY_DIFFUSE, "Diffuse"), (RAY_GLOSSY, "Glossy"), (RAY_TRANSMISSION, "Transmission"))



def _lamp_ray_feature(label: str) -> str:
    """The feature key of a lamp with Ray Visibility ``label`` off."""
    return f"lamp {label.lower()} off"


def _principled_feature(name: str) -> str:
    """The feature key of a Principled BSDF input that is set but not modelled."""
    return f"Principled {name}"


# feature -> what RESTframe does instead (the warning's second half)
UNSUPPORTED = {
    "shadow catcher": "Shadow Catcher is not supported: rendered as an ordinary surface",
    "bump map": "bump and displacement maps are not supported yet: the mesh's own normals are used",
    "volume": "volumes are not supported: volume shaders and Volume objects are left out "
              "(a volume-only material renders black)",
    "hair": "hair strands (particle hair, Curves objects) are not supported: left out",
    "lamp cast shadow off": "Cast Shadow off on a lamp is not supported yet: the lamp casts shadows",
    **{_lamp_ray_feature(label): f"Ray Visibility {label} off on a lamp is not supported for its light yet: the "
                                 f"lamp lights {label.lower()} surfaces through its samples (only bounce rays miss it)"
       for _, label in _LAMP_RAY_VISIBILITY},
    "lamp negative strength": "a negative Strength on a lamp is not supported yet (Cycles subtracts its light): "
                              "the lamp gives no light",
    "area lamp spread": "an area lamp's Spread below 180 degrees is not supported yet: the lamp shines over the "
                        "whole half-space",
    **{_principled_feature(name): f"Principled {name} is not supported yet: rendered without"
       for name, _ in _NOT_MODELLED},
    "Principled Coat Tint": "Principled Coat Tint is not supported: the coat is clear",
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


def _is_on(socket, off) -> bool:
    """Whether a Principled input is linked or set away from the value that turns it off."""
    if upstream(socket) is not None:
        return True
    value = socket.default_value
    return any(float(v) != o for v, o in zip(value[:3], off)) if isinstance(off, tuple) else float(value) != off


def principled_features(node) -> list[str]:
    """The Principled BSDF inputs (keys of ``UNSUPPORTED``) of a Principled node that are set or
    linked but not modelled; Coat Tint only on a coat (its Coat Weight's value above 0)."""
    inputs = node.inputs
    found = [_principled_feature(name) for name, off in _NOT_MODELLED if name in inputs and _is_on(inputs[name], off)]
    if float(inputs["Coat Weight"].default_value) > 0.0 and _is_on(inputs["Coat Tint"], _WHITE):
        found.append("Principled Coat Tint")
    return found


def lamp_features(lamp, light) -> list[str]:
    """The unsupported features (keys of ``UNSUPPORTED``) of a lamp object exported as ``light``
    (a core Light: its power as rendered, Strength x Exposure x its node tree's Emission Strength,
    and the rays that see it): settings its light is rendered without."""
    data, found = lamp.data, []
    if not getattr(data, "use_shadow", True):
        found.append("lamp cast shadow off")
    if light.power < 0.0:
        found.append("lamp negative strength")
    found += [_lamp_ray_feature(label) for bit, label in _LAMP_RAY_VISIBILITY if not light.visibility & bit]
    if data.type == 'AREA' and float(getattr(data, "spread", math.pi)) < math.pi - 1e-6:
        found.append("area lamp spread")
    return found


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
