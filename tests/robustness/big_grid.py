"""The heavy scene of the measurement scripts (Esc latency, memory, export benchmark): a Blender grid
of many triangles moving at 0.5c, a camera and a point light, built with bpy in the running process."""

import resource


def build_grid_scene(subdivisions: int, camera_location=(0.0, -9.0, 6.0)):
    """A fresh RESTframe scene holding the grid (2 * subdivisions^2 triangles); returns the bpy scene.
    The add-on must be registered."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'RESTFRAME'
    scene.restframe.integrator = 'DIRECT'  # measured before path tracing existed: keep comparable
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=subdivisions, y_subdivisions=subdivisions, size=10.0)
    bpy.context.active_object.restframe.velocity = (0.5, 0.0, 0.0)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location, cam.rotation_euler = camera_location, (0.9, 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'POINT'))
    lamp.location = (2.0, -2.0, 5.0)
    scene.collection.objects.link(lamp)
    return scene


def rss_mb(field: str = "VmHWM:") -> float:
    """Resident memory of this process from /proc (VmHWM, the peak, by default: unlike ru_maxrss it
    does not inherit the parent's peak across fork + exec); ru_maxrss where /proc is missing."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(field):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
