"""A manifold stand-in for meshes that cannot carry contacts (scans, multi-part clothing layers): a
voxel-remeshed copy shrink-wrapped onto the original (Contact Edit §9, Fig. 18). Contacts then live on
the proxy, whose surface lies on the original's."""

from __future__ import annotations

import bpy
import numpy as np

from .. import bridge
from .common import ExplainedPoll, guarded, mesh_object, need_mesh

#: Default voxel size, as a fraction of the object's bounding-box diagonal.
VOXEL_FRACTION = 1 / 150


class CONTACT_EDIT_OT_make_proxy(ExplainedPoll, bpy.types.Operator):
    """Make a manifold proxy of the mesh (remeshed and shrink-wrapped onto it) to carry its contacts"""

    bl_idname = "contact_edit.make_proxy"
    bl_label = "Make Contact Proxy"
    bl_options = {"REGISTER", "UNDO"}

    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")
    voxel_size: bpy.props.FloatProperty(
        name="Voxel size", min=0.0, default=0.0, subtype="DISTANCE",
        description="Detail of the proxy (0: 1/150 of the object's size)",
    )  # fmt: skip

    why_not = staticmethod(need_mesh)

    @guarded
    def execute(self, context):
        obj = mesh_object(context, self.object_name or None)
        corners = (
            np.array([obj.matrix_world @ v.co for v in obj.data.vertices]) if obj.data.vertices else None
        )
        if corners is None:
            self.report({"ERROR"}, f"'{obj.name}' has no vertices")
            return {"CANCELLED"}
        size = self.voxel_size or VOXEL_FRACTION * float(np.linalg.norm(np.ptp(corners, axis=0)))
        proxy = bpy.data.objects.new(f"{obj.name} (contact proxy)", obj.data.copy())
        proxy.matrix_world = obj.matrix_world
        context.collection.objects.link(proxy)
        remesh = proxy.modifiers.new("Remesh", "REMESH")
        remesh.mode, remesh.voxel_size = "VOXEL", size
        wrap = proxy.modifiers.new("Shrinkwrap", "SHRINKWRAP")
        wrap.target, wrap.wrap_method = obj, "NEAREST_SURFACEPOINT"
        evaluated = proxy.evaluated_get(context.evaluated_depsgraph_get())
        result = bpy.data.meshes.new_from_object(evaluated)
        template = proxy.data
        proxy.modifiers.clear()
        proxy.data = result
        bpy.data.meshes.remove(template)
        proxy.display_type = "WIRE"
        try:
            mesh = bridge.trimesh(proxy)
        except bridge.BridgeError:
            bpy.data.objects.remove(proxy)
            bpy.data.meshes.remove(result)
            raise
        settings = context.scene.contact_edit
        for role in ("hand", "target"):
            if getattr(settings, role) == obj:
                setattr(settings, role, proxy)
        context.view_layer.objects.active = proxy
        self.report({"INFO"}, f"'{proxy.name}': {mesh.n_faces} faces on the surface of '{obj.name}'")
        return {"FINISHED"}


classes = (CONTACT_EDIT_OT_make_proxy,)
