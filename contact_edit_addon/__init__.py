"""Contact Edit for Blender: pose hands against objects by editing contact areas.

This package is the Blender extension (operators, panels, overlays, batch posing). It also holds the
``contact-edit`` console script (:mod:`contact_edit_addon.commands.cli`), which must import without Blender,
so nothing here imports ``bpy`` at module level: Blender calls :func:`register`, which loads the rest.
"""


def register() -> None:
    from . import registration

    registration.register()


def unregister() -> None:
    from . import registration

    registration.unregister()
