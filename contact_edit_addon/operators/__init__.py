"""The contact tools under ``bpy.ops.contact_edit``: paint, axis, transfer, the edits, the library,
mirroring, proxies, the solve and flex-to-contact. Each works interactively and with explicit properties
in background mode, so scripts run the same tools an animator clicks.

What every operator of the add-on shares is here too: :mod:`.common` (polls that say why not, library
errors reported) and :mod:`.background` (work off Blender's main thread). The operators of a feature
live in its folder: :mod:`..retarget.operators`, :mod:`..device.operators`, :mod:`..assets.operators`.
"""

from . import axis, edit, manage, mirror, paint, proxy, solve, transfer

classes = (
    *paint.classes,
    *axis.classes,
    *transfer.classes,
    *edit.classes,
    *manage.classes,
    *mirror.classes,
    *proxy.classes,
    *solve.classes,
)
