"""Add-on preferences: the solver weights the Reset Weights button restores."""

import bpy

from solver import KEEP_OUT_WEIGHT

WEIGHTS = ("weight_distance", "weight_normal", "weight_prior", "weight_penetration")


class CONTACT_EDIT_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    weight_distance: bpy.props.FloatProperty(
        name="Distance weight",
        description="λd: how strongly contact points are pulled together (paper default 1)",
        default=1.0,
        min=0.0,
    )
    weight_normal: bpy.props.FloatProperty(
        name="Normal weight",
        description="λn: how strongly paired surfaces are turned to face each other (paper default 1)",
        default=1.0,
        min=0.0,
    )
    weight_prior: bpy.props.FloatProperty(
        name="Rest pose weight",
        description="λp: how strongly joints are kept near the rest pose (paper default 10)",
        default=10.0,
        min=0.0,
    )
    weight_penetration: bpy.props.FloatProperty(
        name="Keep out weight",
        description=(
            f"λo: how strongly the hand's skin is kept out of a closed object (not in the paper's Eq. 2; "
            f"default {KEEP_OUT_WEIGHT:g}, 0 leaves it out)"
        ),
        default=KEEP_OUT_WEIGHT,
        min=0.0,
    )

    def draw(self, context):
        column = self.layout.column()
        column.label(text="Default contact solver weights (Contact Edit, Eq. 2)")
        column.prop(self, "weight_distance")
        column.prop(self, "weight_normal")
        column.prop(self, "weight_prior")
        column.prop(self, "weight_penetration")


def solver_weights(context) -> dict[str, float]:
    """The preferred solver weights (the declared defaults when the add-on was registered by a script
    rather than enabled, and so has no stored preferences)."""
    addon = context.preferences.addons.get(__package__)
    if addon is not None:
        return {name: getattr(addon.preferences, name) for name in WEIGHTS}
    properties = CONTACT_EDIT_AP_preferences.bl_rna.properties
    return {name: properties[name].default for name in WEIGHTS}
