"""Data Contact Edit keeps in the .blend file.

Every mesh object has ``contact_edit``: its contact set as a contact file (JSON text: intrinsic points,
axes, links, pairs; see :mod:`geodesics.contacts`), plus a list of its patches (names, colours) that the
sidebar's list shows and that is rebuilt from the set whenever it changes. A hand also has a second set of
the same kind, its retargeting annotation (:mod:`.retarget.annotation`: each patch's axis an axial curve, or
the patch a virtual marker), with its own list; ``layer`` says which of the two the tools edit. The scene
has ``contact_edit``: which objects are the hand and the object, and the solver settings. Keeping the data
in ID properties makes it survive save and reload and follow undo.
"""

import bpy

from solver import KEEP_OUT_WEIGHT

#: How a patch's axis is laid when it is painted or asked for again (in this order: a file keeps an
#: enum's position).
DEFAULT_AXES = [
    ("FARTHEST", "Farthest points", "The geodesic between the patch's two farthest points"),
    ("MEDIAL", "Medial axis", "The patch's smoothed medial axis"),
    (
        "BONE",
        "Along the bone",
        "Down the patch's middle along the bone that weights it most: along the finger on a finger pad, "
        "along the hand on the palm (the farthest points on a mesh no armature deforms)",
    ),
]


def _renamed(self, context) -> None:
    """A name edited in the patch list renames the patch in its set."""
    if self.stored_name and self.name != self.stored_name:
        from . import store

        store.rename(self.id_data, self, context.scene)


def _recoloured(self, context) -> None:
    """A colour set in the patch list is its pair's too, on the other object."""
    from . import store

    store.recolour(self, context.scene)


class CONTACT_EDIT_PG_patch(bpy.types.PropertyGroup):
    """One contact patch as the patch list shows it (the contact set is the source of truth)."""

    name: bpy.props.StringProperty(name="Name", update=_renamed)
    stored_name: bpy.props.StringProperty(options={"HIDDEN"}, description="The patch's name in its set")
    color: bpy.props.FloatVectorProperty(
        name="Colour",
        subtype="COLOR",
        size=4,
        min=0.0,
        max=1.0,
        default=(0.9, 0.4, 0.1, 1.0),
        description="The patch's colour in the viewport, and its pair's on the other object",
        update=_recoloured,
    )
    points: bpy.props.IntProperty(name="Points", min=0)
    parent: bpy.props.StringProperty(name="Parent")
    pair: bpy.props.StringProperty(name="Paired with")
    visible: bpy.props.BoolProperty(name="Visible", default=True)
    # In an annotation only:
    marker: bpy.props.BoolProperty(
        name="Marker",
        description="A virtual marker (the patch's points), not an axial curve (the patch's axis)",
    )
    axis_scale: bpy.props.FloatProperty(
        name="λA",
        min=0.0,
        soft_max=4.0,
        description="How much longer the curve is laid out on this hand than the source's is (as a target "
        "hand). 0: measured, the ratio of the two axes' lengths",
    )
    radial_scale: bpy.props.FloatProperty(
        name="λS",
        min=0.0,
        soft_max=4.0,
        description="How much farther from the curve contacts lie on this hand than on the source (as a "
        "target hand). 0: measured, the ratio of the two curves' girths, or else of their strips' widths",
    )
    girth: bpy.props.FloatProperty(
        name="Girth",
        min=0.0,
        subtype="DISTANCE",
        description="How thick the finger or palm under the curve is (Propose measures it from the bones' "
        "skin): λS is the ratio of two hands' girths. 0: none, λS from the strips' widths",
    )


class CONTACT_EDIT_PG_object(bpy.types.PropertyGroup):
    """The contacts of one mesh object."""

    data: bpy.props.StringProperty(name="Contact data", description="The contact set, as a contact file")
    patches: bpy.props.CollectionProperty(type=CONTACT_EDIT_PG_patch)
    active: bpy.props.IntProperty(name="Active patch", default=0, min=0)
    annotation: bpy.props.StringProperty(
        name="Annotation data", description="The hand's retargeting annotation, as a contact file"
    )
    annotation_patches: bpy.props.CollectionProperty(type=CONTACT_EDIT_PG_patch)
    annotation_active: bpy.props.IntProperty(name="Active curve or marker", default=0, min=0)
    layer: bpy.props.EnumProperty(
        name="Edit",
        items=[
            ("CONTACTS", "Contacts", "The tools edit the object's contact patches"),
            (
                "ANNOTATION",
                "Annotation",
                "The tools edit the hand's retargeting annotation: curves and markers",
            ),
        ],
        default="CONTACTS",
        update=lambda self, context: _redraw(),
    )


def _redraw() -> None:
    from . import store

    store.redraw()


def _is_mesh(_self, obj) -> bool:
    return obj.type == "MESH"


def _check_rig(self, context) -> None:
    """When the hand or its root changes, say at once whether its rig can be solved (the Pose panel)."""
    from . import posing

    posing.check_rig(context.scene)


class CONTACT_EDIT_PG_scene(bpy.types.PropertyGroup):
    """Which objects are posed against each other, and how the pose is solved."""

    hand: bpy.props.PointerProperty(
        name="Hand",
        type=bpy.types.Object,
        poll=_is_mesh,
        update=_check_rig,
        description="The skinned mesh that touches",
    )
    target: bpy.props.PointerProperty(
        name="Object", type=bpy.types.Object, poll=_is_mesh, description="The mesh being touched"
    )
    axis_method: bpy.props.EnumProperty(
        name="Default axis",
        items=DEFAULT_AXES,
        default="FARTHEST",
    )
    brush_radius: bpy.props.IntProperty(
        name="Radius",
        subtype="PIXEL",
        default=30,
        min=1,
        max=1000,
        description="The contact brush's radius in screen pixels (F while painting changes it)",
    )
    brush_density: bpy.props.FloatProperty(
        name="Density",
        default=100.0,
        min=0.01,
        soft_max=2000.0,
        precision=1,
        description="Points per square centimetre of surface that the contact brush paints",
    )
    deformed: bpy.props.BoolProperty(
        name="Use deformed shape",
        description="Work on the hand's current deformed shape instead of its rest shape",
        default=False,
    )
    hand_root: bpy.props.StringProperty(
        name="Hand root",
        description=(
            "The wrist bone where the solved hand starts: bones it does not lead to are left as they are. "
            "Empty: the deform bone where the bones under the contacts meet"
        ),
        update=_check_rig,
    )
    weight_distance: bpy.props.FloatProperty(name="Distance (λd)", default=1.0, min=0.0)
    weight_normal: bpy.props.FloatProperty(name="Normals (λn)", default=1.0, min=0.0)
    weight_prior: bpy.props.FloatProperty(name="Rest pose (λp)", default=10.0, min=0.0)
    weight_penetration: bpy.props.FloatProperty(
        name="Keep out (λo)",
        default=KEEP_OUT_WEIGHT,
        min=0.0,
        description="How strongly the hand's skin is kept out of a closed object (0: not at all)",
    )
    keyframe: bpy.props.BoolProperty(
        name="Keyframe",
        description="Key every pose Solve, Flex, Wrap and Mirror make on the current frame, from their "
        "buttons, hotkeys and scripts alike (a script can still say otherwise)",
        default=False,
    )
    last_solve: bpy.props.StringProperty(name="Last solve", description="How the last solve went")


classes = (CONTACT_EDIT_PG_patch, CONTACT_EDIT_PG_object, CONTACT_EDIT_PG_scene)


def register() -> None:
    bpy.types.Object.contact_edit = bpy.props.PointerProperty(type=CONTACT_EDIT_PG_object)
    bpy.types.Scene.contact_edit = bpy.props.PointerProperty(type=CONTACT_EDIT_PG_scene)


def unregister() -> None:
    del bpy.types.Scene.contact_edit
    del bpy.types.Object.contact_edit
