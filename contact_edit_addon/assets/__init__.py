"""Procedural hands and objects as Blender objects: :mod:`.builders` makes them from plain Blender data
(the demo, the tests and scripts call it), :mod:`.rigify` puts the procedural hand on a Rigify human, and
:mod:`.operators` offers them in the viewport's Add menu.

The builders are this package's public face: ``from contact_edit_addon import assets`` then
``assets.example_scene(context, where)``, ``assets.hand_objects(hand, name, collection)`` or
``assets.mesh_object(name, mesh, collection)``.
"""

from .builders import MUG_HEIGHT, MUG_RADIUS, OBJECTS, PALM_GAP, example_scene, hand_objects, mesh_object

__all__ = ["MUG_HEIGHT", "MUG_RADIUS", "OBJECTS", "PALM_GAP", "example_scene", "hand_objects", "mesh_object"]
