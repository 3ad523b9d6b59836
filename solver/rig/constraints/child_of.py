"""The Child Of constraint (``childof_evaluate``): the target as a parent, with its inverse matrix and the
channels it passes on."""

from __future__ import annotations

import numpy as np

from ..math_matrix import mat4_to_size, with_translation
from ..math_rotation import loc_eulO_size_to_mat4, mat4_to_eulO
from ..stack import matmul
from .model import DEFAULTS


def childof_evaluate(cs, cob, tars, ctx):
    """Child Of (``childof_evaluate``): the owner under the target as under a parent, channels as set."""
    T = tars[0]
    v = cs.values
    flags = {k: cs.get(k) for k in DEFAULTS["CHILD_OF"] if k.startswith("use_")}
    target_order = cs.slots[0].euler_order
    if all(flags.values()):
        parmat, invmat = T, v["inverse_matrix"]
    else:
        loc, eul, size = T[..., :3, 3], mat4_to_eulO(T, target_order), mat4_to_size(T)
        loco, eulo, sizeo = v["_inverse_loc"], v["_inverse_euler"], v["_inverse_size"]
        loc_on = np.array([flags[f"use_location_{c}"] for c in "xyz"])
        rot_on = np.array([flags[f"use_rotation_{c}"] for c in "xyz"])
        size_on = np.array([flags[f"use_scale_{c}"] for c in "xyz"])
        loc, loco = np.where(loc_on, loc, 0.0), np.where(loc_on, loco, 0.0)
        eul, eulo = np.where(rot_on, eul, 0.0), np.where(rot_on, eulo, 0.0)
        size, sizeo = np.where(size_on, size, 1.0), np.where(size_on, sizeo, 1.0)
        parmat = loc_eulO_size_to_mat4(loc, eul, size, target_order)
        invmat = loc_eulO_size_to_mat4(loco, eulo, sizeo, ctx.order)
    out = matmul(matmul(parmat, invmat), cob)
    keep = [not flags[f"use_location_{c}"] for c in "xyz"]
    if any(keep):
        out = with_translation(out, np.where(keep, cob[..., :3, 3], out[..., :3, 3]))
    return out
