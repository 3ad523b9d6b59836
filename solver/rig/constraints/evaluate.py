"""Which ``*_evaluate`` function evaluates each modelled constraint type, and what they read besides the
constraint stack and the matrices."""

from __future__ import annotations

from dataclasses import dataclass

from ..bones import BoneStack
from ..spaces import World
from .armature import armdef_evaluate
from .child_of import childof_evaluate
from .copying import loclike_evaluate, rotlike_evaluate, sizelike_evaluate, translike_evaluate
from .limits import loclimit_evaluate, rotlimit_evaluate, sizelimit_evaluate
from .tracking import damptrack_evaluate, locktrack_evaluate, stretchto_evaluate, trackto_evaluate


@dataclass
class Context:
    """What an ``*_evaluate`` function reads besides the stack and the matrices: the owners, the armature's
    world matrix, the Euler order the type decomposes in, and (Armature) the target bones' poses."""

    owner: BoneStack
    world: World
    order: str
    poses: list  # the target bones' pose matrices, per slot (Armature)


#: The ``*_evaluate`` function of each modelled constraint type.
EVALUATE = {
    "COPY_LOCATION": loclike_evaluate,
    "COPY_ROTATION": rotlike_evaluate,
    "COPY_SCALE": sizelike_evaluate,
    "COPY_TRANSFORMS": translike_evaluate,
    "STRETCH_TO": stretchto_evaluate,
    "DAMPED_TRACK": damptrack_evaluate,
    "TRACK_TO": trackto_evaluate,
    "LOCKED_TRACK": locktrack_evaluate,
    "LIMIT_ROTATION": rotlimit_evaluate,
    "LIMIT_LOCATION": loclimit_evaluate,
    "LIMIT_SCALE": sizelimit_evaluate,
    "ARMATURE": armdef_evaluate,
    "CHILD_OF": childof_evaluate,
}
