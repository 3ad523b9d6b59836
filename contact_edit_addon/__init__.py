"""Contact Edit for Blender: pose hands against objects by editing contact areas.

This package is the Blender extension, in folders by feature:

* :mod:`.operators` — the contact tools (paint, axis, transfer, the edits, the library, mirroring,
  proxies, the solve, flex-to-contact), and what every operator shares: polls that say why not, errors
  reported, and work off Blender's main thread (:mod:`.operators.background`);
* :mod:`.ui` — the sidebar's Contact tab, the viewport overlay, the hotkeys;
* :mod:`.bridge` — Blender data as the libraries' numpy types, and back;
* :mod:`.assets` — the procedural hands and objects as Blender objects, and the Add menu;
* :mod:`.retarget` — a scene's hand-object motion retargeted onto another hand, and the hands' annotations;
* :mod:`.device` — an armature driven live by the puppet device;
* :mod:`.commands` — the ``contact-edit`` console script, batch posing, the demo, the build, benchmarks.

Beside them, what they all share: :mod:`.properties` (the contacts and settings kept in the .blend),
:mod:`.store` (reading and writing them), :mod:`.posing` (contact IK for a scene), :mod:`.preferences` and
:mod:`.registration`. The console script must import without Blender, so nothing here imports ``bpy`` at
module level: Blender calls :func:`register`, which loads the rest.
"""


def register() -> None:
    from . import registration

    registration.register()


def unregister() -> None:
    from . import registration

    registration.unregister()
