"""Properties-editor panels for RESTframe, and Blender's own panels enabled for it.

Like the Cycles add-on: our panels poll on ``COMPAT_ENGINES``, and Blender's
engine-neutral panels (format, output, frame range, camera, colour management,
material slots and node surfaces) get ``'RESTFRAME'`` added to theirs.
"""

from __future__ import annotations

import math

import bpy
from bpy.types import Panel

from . import motion_query
from .core import validation
from .properties import speed_of

ENGINE = 'RESTFRAME'

# Blender panels (declared for BLENDER_RENDER) that do not apply to RESTframe.
_EXCLUDE_PANELS = {
    'DATA_PT_light',  # replaced by RESTFRAME_LIGHT_PT_light, which shows what the tracer uses
    'NODE_DATA_PT_light',  # shares DATA_PT_light's COMPAT_ENGINES set
    'DATA_PT_preview',  # no preview renders
    'MATERIAL_PT_preview',
    'RENDER_PT_freestyle',  # Freestyle lines are drawn by Blender's internal engines only
    'MATERIAL_PT_freestyle_line',
}
# Engine-specific Blender panels that are right for RESTframe too (node-based surfaces).
_EXTRA_PANELS = (
    'DATA_PT_camera_dof',  # the camera's Depth of Field, read as Cycles reads it
    'DATA_PT_camera_dof_aperture',
    'EEVEE_MATERIAL_PT_context_material',
    'EEVEE_MATERIAL_PT_surface',
    'EEVEE_WORLD_PT_surface',
)

_MOTION_TYPES = {'MESH', 'CURVE', 'SURFACE', 'FONT', 'META', 'CURVES', 'POINTCLOUD', 'VOLUME',
                 'EMPTY', 'LIGHT', 'CAMERA'}


class RestframeButtonsPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


# --------------------------------------------------------------------------- render
class RESTFRAME_RENDER_PT_relativity(RestframeButtonsPanel, Panel):
    bl_label = "Relativity"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = True
        scene = context.scene
        rf = scene.restframe
        col = layout.column()
        col.prop(rf, "integrator")
        col.prop(rf, "light_speed")
        col.prop(rf, "reference_frame")
        col.prop(rf, "motion_tolerance")
        col.prop(rf, "show_velocity")
        col = layout.column(align=True)
        seconds = motion_query.observation_time(scene)
        col.label(text=f"Frame {scene.frame_current}: t = {seconds:.6g} s, c·t = {rf.light_speed * seconds:.6g}",
                  icon='TIME')


class RESTFRAME_RENDER_PT_sampling(RestframeButtonsPanel, Panel):
    bl_label = "Sampling"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        rf = context.scene.restframe
        col = layout.column()
        col.prop(rf, "samples")
        if rf.integrator == 'DIRECT':  # Path Tracing: in Light Paths, as the total
            col.prop(rf, "max_bounces", text="Mirror/Glass Bounces")


class RESTFRAME_RENDER_PT_light_paths(RestframeButtonsPanel, Panel):
    """Cycles' Light Paths: the bounce limits and clamps of the path tracer."""

    bl_label = "Light Paths"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.scene.restframe.integrator == 'PATH'

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        rf = context.scene.restframe
        col = layout.column(heading="Max Bounces", align=True)
        col.prop(rf, "max_bounces", text="Total")
        col.prop(rf, "diffuse_bounces", text="Diffuse")
        col.prop(rf, "glossy_bounces", text="Glossy")
        col.prop(rf, "transmission_bounces", text="Transmission")
        col = layout.column(heading="Clamping", align=True)
        col.prop(rf, "clamp_direct", text="Direct Light")
        col.prop(rf, "clamp_indirect", text="Indirect Light")


class RESTFRAME_RENDER_PT_doppler(RestframeButtonsPanel, Panel):
    bl_label = "Doppler"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        rf = context.scene.restframe
        col = layout.column()
        col.prop(rf, "doppler_mode")
        col.prop(rf, "searchlight")
        sub = col.column()
        sub.active = rf.doppler_mode == 'SPECTRAL'
        sub.prop(rf, "spectral_samples")
        sub = col.column()
        sub.active = rf.doppler_mode != 'FACTOR'
        sub.prop(rf, "normalize_exposure")
        sub = col.column()
        sub.active = rf.doppler_mode == 'FACTOR'
        sub.prop(rf, "doppler_range_auto")
        row = sub.column(align=True)
        row.active = not rf.doppler_range_auto
        row.prop(rf, "doppler_range", index=0, text="Black")
        row.prop(rf, "doppler_range", index=1, text="White")
        sub.prop(rf, "doppler_levels")
        levels_error = validation.doppler_levels_error(rf.doppler_levels)
        if levels_error is not None and rf.doppler_mode == 'FACTOR':
            sub.label(text=levels_error, icon='ERROR')


class RESTFRAME_RENDER_PT_motion_blur(RestframeButtonsPanel, Panel):
    """Blender's Motion Blur settings and the rolling shutter, as Cycles shows them."""

    bl_label = "Motion Blur"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.scene.render, "use_motion_blur", text="")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        render, rf = context.scene.render, context.scene.restframe
        layout.active = render.use_motion_blur
        col = layout.column()
        col.prop(render, "motion_blur_position", text="Position")
        col.prop(render, "motion_blur_shutter")
        col.separator()
        col.prop(rf, "rolling_shutter_type", text="Rolling Shutter")
        sub = col.column()
        sub.active = rf.rolling_shutter_type != 'NONE'
        sub.prop(rf, "rolling_shutter_duration")
        col.label(text="Shutter times run on the camera's own clock", icon='TIME')


class RESTFRAME_RENDER_PT_motion_blur_curve(RestframeButtonsPanel, Panel):
    bl_label = "Shutter Curve"
    bl_parent_id = "RESTFRAME_RENDER_PT_motion_blur"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        render = context.scene.render
        layout.active = render.use_motion_blur
        layout.template_curve_mapping(render, "motion_blur_shutter_curve")
        row = layout.row(align=True)
        for shape, icon in (('SMOOTH', 'SMOOTHCURVE'), ('ROUND', 'SPHERECURVE'), ('ROOT', 'ROOTCURVE'),
                            ('SHARP', 'SHARPCURVE'), ('LINE', 'LINCURVE'), ('MAX', 'NOCURVE')):
            row.operator("render.shutter_curve_preset", icon=icon, text="").shape = shape


class RESTFRAME_RENDER_PT_film(RestframeButtonsPanel, Panel):
    bl_label = "Film"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(context.scene.render, "film_transparent", text="Transparent")


class RESTFRAME_RENDER_PT_performance(RestframeButtonsPanel, Panel):
    bl_label = "Performance"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        render = context.scene.render
        col = layout.column()
        col.prop(render, "threads_mode")
        sub = col.column()
        sub.enabled = render.threads_mode == 'FIXED'
        sub.prop(render, "threads")
        col.prop(context.scene.restframe, "parallelism")
        col.prop(context.scene.restframe, "tile_size")
        col.prop(render, "use_persistent_data", text="Persistent Data")


# --------------------------------------------------------------------------- view layer
class RESTFRAME_VIEWLAYER_PT_passes(RestframeButtonsPanel, Panel):
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        view_layer = context.view_layer
        col = layout.column(heading="Data", align=True)
        col.prop(view_layer, "use_pass_z")
        col.prop(view_layer, "use_pass_normal")
        col.prop(view_layer, "use_pass_object_index")
        col = layout.column(heading="Denoising", align=True)
        col.prop(view_layer.restframe, "denoising_store_passes", text="Denoising Data")
        col = layout.column(align=True)
        col.label(text="Doppler, Emission Time and Object Time are always rendered", icon='INFO')


# --------------------------------------------------------------------------- object
def _draw_clock(col, obj, scene, speed: bool = True):
    """The object's own clock at the rendered frame (and its speed there, on a world line)."""
    seconds, beta = motion_query.clock(obj, scene)
    if seconds != seconds:  # NaN: the motion reaches c
        col.label(text="The keyed motion reaches the speed of light", icon='ERROR')
        return
    if speed:
        col.label(text=f"Speed \u03b2 = {math.sqrt(sum(b * b for b in beta)):.9g} c at this frame")
    col.label(text=f"Proper time {seconds:.9g} s (own clock at this frame)", icon='TIME')


class RESTFRAME_OBJECT_PT_motion(RestframeButtonsPanel, Panel):
    bl_label = "Relativistic Motion"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.object is not None and context.object.type in _MOTION_TYPES

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        obj = context.object
        rf = obj.restframe
        col = layout.column()
        observer_or_lamp = obj.type in {'LIGHT', 'CAMERA'}
        col.prop(rf, "motion")
        if rf.is_animated:
            box = layout.box()
            root = motion_query.assembly_root(obj)
            if root != obj:
                box.label(text=f"World line: that of its parent '{root.name}' (the same Motion)", icon='LINKED')
            else:
                box.label(text="World line: the keyframed location (own keys, parents static)", icon='ANIM')
            if not motion_query.has_animated_location(obj):
                box.label(text="The location has no keyframes: the object stays at rest", icon='INFO')
            if obj.type == 'LIGHT' and obj.data.type == 'SUN':
                box.label(text="A sun has no world line: it stays at rest", icon='ERROR')
            elif obj.type == 'CAMERA':
                box.label(text="Accelerating observer: the image forms in its momentary rest frame",
                          icon='CAMERA_DATA')
            elif obj.type == 'LIGHT':
                box.label(text="Light leaves it at its retarded positions", icon='LIGHT')
            if any(rf.angular_velocity):
                box.label(text="Angular Velocity is ignored with Motion = Animation", icon='ERROR')
            if observer_or_lamp:
                _draw_clock(box.column(align=True), obj, context.scene)
            return
        if not observer_or_lamp:  # lamps and cameras do not spin
            col.prop(rf, "angular_velocity")
        col.prop(rf, "velocity", text="Velocity (c)")
        col.prop(rf, "lorentz_factor")

        box = layout.box()
        col = box.column(align=True)
        try:
            validation.check_velocity(rf.velocity, rf.lorentz_factor, obj.name)
        except ValueError as error:
            col.label(text=str(error).partition(": ")[2], icon='ERROR')
        else:
            beta, gamma, rapidity = speed_of(rf.velocity, rf.lorentz_factor)  # double precision
            if gamma > 1e3:  # show how far below c, which a decimal fraction would hide
                col.label(text=f"Speed \u03b2 = 1 \u2212 {1.0 / (gamma * gamma * (1.0 + beta)):.6g} c")
            else:
                col.label(text=f"Speed \u03b2 = {beta:.9g} c")
            col.label(text=f"Lorentz factor \u03b3 = {gamma:.9g}")
            col.label(text=f"Rapidity = {rapidity:.6g}")
            if observer_or_lamp:
                _draw_clock(col, obj, context.scene, speed=False)
        if motion_query.rides_with_parent(obj):
            box.label(text=f"Rides with its parent '{obj.parent.name}' (no motion of its own)", icon='LINKED')
        if not rf.is_moving:
            return
        if obj.type == 'CAMERA':
            box.label(text="Moving observer: the image forms in the camera's frame", icon='CAMERA_DATA')
        root = motion_query.assembly_root(obj)
        if root != obj:
            box.label(text=f"Moves rigidly with its parent '{root.name}' (assembly pivot)", icon='LINKED')
        if motion_query.has_animated_location(obj):
            warn = layout.column(align=True)
            warn.alert = True
            warn.label(text="Location is keyframed: the object will jump between frames", icon='ERROR')
            warn.label(text="Set Motion to Animation to follow the keyframed path")


# --------------------------------------------------------------------------- light
class RESTFRAME_LIGHT_PT_light(RestframeButtonsPanel, Panel):
    bl_label = "Light"
    bl_context = "data"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.light is not None

    def draw(self, context):
        layout = self.layout
        light = context.light
        layout.row().prop(light, "type", expand=True)
        layout.use_property_split = True
        col = layout.column()
        if hasattr(light, "use_temperature"):  # Blender 4.5+
            row = col.row(heading="Temperature")
            row.prop(light, "use_temperature", text="")
            sub = row.row()
            sub.active = light.use_temperature
            sub.prop(light, "temperature", text="")
        col.prop(light, "color", text="Tint" if getattr(light, "use_temperature", False) else "Color")
        col.prop(light, "energy")
        if hasattr(light, "exposure"):
            col.prop(light, "exposure")
        col.separator()
        if light.type in {'POINT', 'SPOT'}:
            col.prop(light, "shadow_soft_size", text="Radius")
        elif light.type == 'SUN':
            col.prop(light, "angle")
        elif light.type == 'AREA':
            col.prop(light, "shape")
            sub = col.column(align=True)
            if light.shape in {'SQUARE', 'DISK'}:
                sub.prop(light, "size")
            else:
                sub.prop(light, "size", text="Size X")
                sub.prop(light, "size_y", text="Y")
        if light.type == 'SPOT':
            col.separator()
            col.prop(light, "spot_size", text="Spot Size")
            col.prop(light, "spot_blend", text="Blend", slider=True)


classes = (
    RESTFRAME_RENDER_PT_relativity,
    RESTFRAME_RENDER_PT_sampling,
    RESTFRAME_RENDER_PT_light_paths,
    RESTFRAME_RENDER_PT_doppler,
    RESTFRAME_RENDER_PT_motion_blur,
    RESTFRAME_RENDER_PT_motion_blur_curve,
    RESTFRAME_RENDER_PT_film,
    RESTFRAME_RENDER_PT_performance,
    RESTFRAME_VIEWLAYER_PT_passes,
    RESTFRAME_OBJECT_PT_motion,
    RESTFRAME_LIGHT_PT_light,
)


def get_panels():
    """Blender's panels that should also show for RESTframe."""
    panels = [
        panel for panel in bpy.types.Panel.__subclasses__()
        if 'BLENDER_RENDER' in getattr(panel, "COMPAT_ENGINES", ())
        and panel.__name__ not in _EXCLUDE_PANELS
        and not panel.__name__.startswith("VIEWLAYER_PT_freestyle")
    ]
    panels += [getattr(bpy.types, name) for name in _EXTRA_PANELS if hasattr(bpy.types, name)]
    return panels


_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    for panel in get_panels():
        panel.COMPAT_ENGINES.add(ENGINE)


def unregister():
    for panel in get_panels():
        panel.COMPAT_ENGINES.discard(ENGINE)
    _unregister_classes()
