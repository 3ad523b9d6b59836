"""The operators under ``bpy.ops.contact_edit``: each works interactively and with explicit properties
in background mode, so scripts run the same tools an animator clicks."""

from . import annotation, axis, device, edit, manage, mirror, paint, proxy, retarget, solve, transfer

classes = (
    *paint.classes,
    *axis.classes,
    *transfer.classes,
    *edit.classes,
    *manage.classes,
    *mirror.classes,
    *proxy.classes,
    *solve.classes,
    *retarget.classes,
    *annotation.classes,
    *device.classes,
)
