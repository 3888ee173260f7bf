# Fitted Cloth settings onto a Blender Cloth modifier. This file is whole: it imports only bpy, so
# `clothfit export-blender-cloth RESULT --python` prints it, followed by one call with the fit's values,
# as a script that runs in any Blender 4.2+ (Text Editor > Run Script, or blender --python FILE); the
# add-on's Apply Blender Cloth calls the same function.
import bpy


class ClothTargetError(RuntimeError):
    """No object to put the settings on, or no Cloth modifier on it (a one-line message)."""


def set_frame_rate(scene, fps):
    """Set the scene's frame rate to ``fps`` frames per second (a fractional rate through fps_base)."""
    if abs(fps - round(fps)) < 1e-9:
        scene.render.fps, scene.render.fps_base = int(round(fps)), 1.0
    else:
        base = 1.001 if abs(fps * 1.001 - round(fps * 1.001)) < 1e-6 else round(fps) / fps
        scene.render.fps, scene.render.fps_base = int(round(fps * base)), base


def find_cloth_modifier(object_name=None):
    """The object named ``object_name`` (else the active object) and its Cloth modifier, found by
    type; ``ClothTargetError`` when there is no such object or it has no Cloth modifier."""
    if object_name:
        obj = bpy.data.objects.get(object_name)
        if obj is None:
            raise ClothTargetError(f"no object named {object_name!r} in this Blender file")
    else:
        obj = bpy.context.view_layer.objects.active
        if obj is None:
            raise ClothTargetError("no active object: select the cloth object (or name it with --object)")
    for m in obj.modifiers:
        if m.type == "CLOTH":
            return obj, m
    raise ClothTargetError(f"object {obj.name!r} has no Cloth modifier: add one (Properties > Physics > Cloth) first")


def apply_cloth_settings(settings, fps, object_name=None, set_fps=True, scene=None):
    """Put ``settings`` (ClothSettings name -> value) on the Cloth modifier of the object named
    ``object_name`` (else the active object) and set the scene's frame rate to ``fps``, the rate the
    settings were fitted for (Blender's cloth moves per frame). With ``set_fps=False`` a scene at
    another rate is refused. ``scene``: the context's unless given. Returns the object."""
    obj, mod = find_cloth_modifier(object_name)
    scene = scene or bpy.context.scene
    rate = scene.render.fps / scene.render.fps_base
    if abs(rate - fps) > 1e-6:
        if not set_fps:
            raise ClothTargetError(
                f"the settings are for {fps:g} fps but the scene runs at {rate:g} fps: "
                f"Blender's cloth moves per frame, so they would move it differently"
            )
        set_frame_rate(scene, fps)
    cs = mod.settings
    for name, value in settings.items():
        setattr(cs, name, value)
    return obj


def add_colliders(colliders, collision_settings, cloth_object_name=None, scene=None):
    """The colliders of the fit's scene: each ``{"name", "vertices", "faces", "thickness_outer",
    "cloth_friction"}`` a mesh object with a Collision modifier (an object of the same name is
    replaced), and collisions on for the Cloth modifier of the object named ``cloth_object_name``
    (else the active object; none is skipped) with ``collision_settings`` (distance_min,
    collision_quality). Returns the collider objects."""
    scene = scene or bpy.context.scene
    made = []
    for c in colliders:
        old = bpy.data.objects.get(c["name"])
        if old is not None:
            bpy.data.objects.remove(old, do_unlink=True)
        me = bpy.data.meshes.new(c["name"])
        me.from_pydata(c["vertices"], [], c["faces"])
        me.update()
        obj = bpy.data.objects.new(c["name"], me)
        scene.collection.objects.link(obj)
        obj.modifiers.new("Collision", "COLLISION")
        obj.collision.use_culling = True
        obj.collision.thickness_outer = c["thickness_outer"]
        obj.collision.cloth_friction = c["cloth_friction"]
        made.append(obj)
    try:
        _, mod = find_cloth_modifier(cloth_object_name)
    except ClothTargetError:
        return made
    cs = mod.collision_settings
    cs.use_collision = True
    for name, value in collision_settings.items():
        setattr(cs, name, value)
    return made
