"""Contact Edit for Blender: the Blender extension (operators, panels, overlays, batch posing).

The extension itself arrives with the add-on issue. This package already holds the ``contact-edit``
console script (:mod:`contact_edit_addon.cli`), which must import without Blender.
"""
