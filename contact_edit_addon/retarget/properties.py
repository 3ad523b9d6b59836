"""What the scene keeps about retargeting (``scene.contact_edit_retarget``): the source hand and the object
it holds, the target hand, the frames, the annotation, where the solved frames are kept, and how the last
retarget went. Saved with the .blend, so a batch script sets them once and calls the operator.
"""

import bpy


def _is_mesh(_self, obj) -> bool:
    return obj.type == "MESH"


class CONTACT_EDIT_PG_retarget(bpy.types.PropertyGroup):
    """A retarget of the scene's hand-object motion onto another hand."""

    source: bpy.props.PointerProperty(
        name="Source hand",
        type=bpy.types.Object,
        poll=_is_mesh,
        description="The animated hand mesh whose motion is retargeted (skinned, shape keys or a cache)",
    )
    held: bpy.props.PointerProperty(
        name="Object",
        type=bpy.types.Object,
        poll=_is_mesh,
        description="The object the source hand moves (rigidly, by its transform)",
    )
    target: bpy.props.PointerProperty(
        name="Target hand",
        type=bpy.types.Object,
        poll=_is_mesh,
        description="The hand mesh, deformed by an armature, that gets the motion as an action",
    )
    use_scene_range: bpy.props.BoolProperty(
        name="Scene frame range",
        default=True,
        description="Retarget the scene's frame range (else the range given here)",
    )
    frame_start: bpy.props.IntProperty(name="Start", default=1, min=0)
    frame_end: bpy.props.IntProperty(name="End", default=250, min=0)
    annotation: bpy.props.StringProperty(
        name="Annotation",
        subtype="FILE_PATH",
        description=(
            "An annotation.json made for these two hands (the format contact-edit retarget writes). "
            "Empty: the annotations drawn on the two hands (Retarget > Annotation), else the built-in one "
            "of the procedural hands of Add > Contact Edit"
        ),
    )
    contacts: bpy.props.BoolProperty(
        name="Contacts",
        default=True,
        description="Find where the source hand touches the object and carry the contacts over (else only "
        "the hand's markers are followed)",
    )
    workers: bpy.props.IntProperty(
        name="Processes",
        default=0,
        min=0,
        soft_max=64,
        description="Processes that solve frames at once (0: one per CPU core)",
    )
    folder: bpy.props.StringProperty(
        name="Frames folder",
        subtype="DIR_PATH",
        description=(
            "Where the solved frames and the outputs are kept, so that a stopped retarget goes on from "
            "them. Empty: beside the .blend file (or in a temporary folder while it is unsaved)"
        ),
    )
    action_name: bpy.props.StringProperty(
        name="Action", description="The new action's name (empty: '<target> from <source>')"
    )
    last: bpy.props.StringProperty(name="Last retarget", description="How the last retarget went")


classes = (CONTACT_EDIT_PG_retarget,)


def register() -> None:
    bpy.types.Scene.contact_edit_retarget = bpy.props.PointerProperty(type=CONTACT_EDIT_PG_retarget)


def unregister() -> None:
    del bpy.types.Scene.contact_edit_retarget
