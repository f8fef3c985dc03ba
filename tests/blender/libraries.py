"""Library .blend files for the Blender-side check scripts: a character saved in a library, linked into a shot
file as objects or as a collection made a library override (what a studio does with a character).

Imported by check scripts after :mod:`harness` (which imports bpy).
"""

import bpy

CHARACTER = "Character"


def save_character(path, objects):
    """Move ``objects`` (of the scene's collection) into a new collection :data:`CHARACTER` and save the open file as
    the library ``path``."""
    character = bpy.data.collections.new(CHARACTER)
    bpy.context.scene.collection.children.link(character)
    for obj in objects:
        character.objects.link(obj)
        bpy.context.scene.collection.objects.unlink(obj)
    bpy.ops.wm.save_as_mainfile(filepath=path)


def link_objects(path, names):
    """Link the objects ``names`` of the library ``path`` into the scene of the open file; returns them in order."""
    with bpy.data.libraries.load(path, link=True) as (_source, target):
        target.objects = list(names)
    linked = [next(o for o in target.objects if o.name == n) for n in names]
    for obj in linked:
        bpy.context.scene.collection.objects.link(obj)
    return linked


def override_character(path, editable):
    """Link the collection :data:`CHARACTER` of the library ``path`` into the open file and make it a library
    override (what Make Library Override does; ``editable``: fully editable); returns the scene and the override
    collection.  Blender overrides the objects and leaves their meshes linked (unless a key is driven by an object of
    the character): ``mesh.override_create(remap_local_usages=True)`` makes a mesh an override too."""
    with bpy.data.libraries.load(path, link=True) as (_source, target):
        target.collections = [CHARACTER]
    scene = bpy.context.scene
    scene.collection.children.link(target.collections[0])
    return scene, target.collections[0].override_hierarchy_create(scene, bpy.context.view_layer,
                                                                  do_fully_editable=editable)
