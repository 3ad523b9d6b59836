"""How Blender places a bone under its parent: ``BoneParentTransform`` and the inherit flags
(``armature.cc``), for one bone or a stack of them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import SolverError
from .bones import Bone, BoneStack
from .math_matrix import (
    affine,
    cbrt_abs,
    det3,
    inverse_affine,
    mat4_to_size,
    mat4_to_size_fix_shear,
    mul_v3_m4v3,
    normalize_m4_ex,
    orthogonalize_m4_stable,
    rescale_m4,
    with_translation,
)
from .stack import from_single_stack, matmul, to_single_stack

_ZERO3 = np.zeros(3)


class Parenting:
    """``BoneParentTransform`` of a stack of bones (stack layout), with its inverse on demand.

    ``rotscale`` and ``loc`` (g, K, 4, 4) and ``post`` (g, K, 3) or None (no post scale) as Blender's
    ``BKE_bone_parent_transform_calc_from_matrices``; :meth:`to_pose` and :meth:`to_local` are
    ``BKE_armature_mat_bone_to_pose`` and ``BKE_armature_mat_pose_to_bone``.
    """

    def __init__(self, stack: BoneStack, parent_pose):
        self.stack = stack
        self._parent_pose = parent_pose
        self._transform = None
        self._rotscale_inverse = None
        self._loc_inverse = None

    @property
    def parent_pose(self):
        """(g, K, 4, 4) the parents' pose matrices (not needed for roots)."""
        if self._parent_pose is None and not self.stack.root:
            raise SolverError(f"bones {', '.join(self.stack.names[:4])} need their parents' poses")
        return self._parent_pose

    def _calc(self):
        if self._transform is None:
            self._transform = _parent_transform(self.stack, self.parent_pose)
        return self._transform

    @property
    def rotscale(self):
        """(g, K, 4, 4) the rotation and scale transform."""
        return self._calc()[0]

    @property
    def loc(self):
        """(g, K, 4, 4) the location transform, or None when it is ``rotscale`` itself."""
        return self._calc()[1]

    @property
    def post(self):
        """(g, K, 3) the post scale, or None for none."""
        return self._calc()[2]

    @property
    def rotscale_inverse(self):
        """(g, K, 4, 4) the inverse of :attr:`rotscale`."""
        if self._rotscale_inverse is None:
            self._rotscale_inverse = inverse_affine(self.rotscale)
        return self._rotscale_inverse

    @property
    def loc_inverse(self):
        """(g, K, 4, 4) the inverse of :attr:`loc`, or None when that is None."""
        if self._loc_inverse is None and self.loc is not None:
            self._loc_inverse = inverse_affine(self.loc)
        return self._loc_inverse

    def head(self):
        """(g, K, 3) where a connected bone's head goes: the translation its pose matrix gets from
        channels without translation."""
        s = self.stack
        if s.root:
            return s.offset_translation
        if s.full:
            return matmul(self.parent_pose, s.head_column)[..., :3, 0]
        return (self.rotscale if self.loc is None else self.loc)[..., :3, 3]

    def to_pose(self, local, connect: bool = False):
        """``BKE_armature_mat_bone_to_pose`` of local matrices (g, K, 4, 4), or of the identity (None);
        ``connect`` drops their translations first (Blender's connected bones)."""
        s = self.stack
        if local is not None and connect:
            local = with_translation(local, _ZERO3)
        if s.full and s.local_location:
            P = self.parent_pose
            if local is None:
                return matmul(P, s.offset)
            if local.shape[1] == 1:
                return matmul(P, s.offset @ local)
            return matmul(self.rotscale, local)
        if s.root:
            offs = s.offset
            if local is None:
                return offs.copy()
            out = matmul(offs, local)
            if not s.local_location:
                out = with_translation(out, local[..., :3, 3] + s.offset_translation)
            return out
        out = self.rotscale if local is None else matmul(self.rotscale, local)
        if self.loc is not None:
            t = self.loc[..., :3, 3] if local is None else mul_v3_m4v3(self.loc, local[..., :3, 3])
            out = with_translation(out, t)
        elif local is None:
            out = out.copy()
        if self.post is not None:
            out = rescale_m4(out, self.post)
        return out

    def to_local(self, pose):
        """``BKE_armature_mat_pose_to_bone`` of pose matrices (g, K, 4, 4)."""
        s = self.stack
        if s.root:
            out = matmul(s.rest_inverse, pose)
            if not s.local_location:
                out = with_translation(out, pose[..., :3, 3] - s.offset_translation)
            return out
        out = matmul(self.rotscale_inverse, pose)
        if self.loc is not None:
            out = with_translation(out, mul_v3_m4v3(self.loc_inverse, pose[..., :3, 3]))
        if self.post is not None:
            ok = self.post.real != 0
            out = rescale_m4(out, np.where(ok, 1.0 / np.where(ok, self.post, 1.0), 0.0))
        return out


def _parent_transform(stack: BoneStack, P):
    """(rotscale, loc or None, post or None) of ``BKE_bone_parent_transform_calc_from_matrices`` for a
    stack; loc None means loc = rotscale, post None means no post-scale."""
    offs = stack.offset
    if stack.root:
        rotscale = offs
        if stack.local_location:
            return rotscale, None, None
        loc = np.broadcast_to(np.eye(4), offs.shape).copy()
        loc[..., :3, 3] = offs[..., :3, 3]
        return rotscale, loc, None
    mode = stack.inherit_scale
    use_rotation = stack.inherit_rotation
    full = use_rotation and mode == "FULL"
    post = None
    if full:
        rotscale = matmul(P, offs)
    else:
        if use_rotation:
            tmat = P
            if mode in ("NONE", "AVERAGE"):
                tmat = orthogonalize_m4_stable(tmat, 1, unit=True)
            elif mode == "ALIGNED":
                tmat, post = normalize_m4_ex(orthogonalize_m4_stable(tmat, 1, unit=False))
            elif mode == "NONE_LEGACY":
                tmat, _ = normalize_m4_ex(tmat)
        else:
            tmat = stack.parent_rest
            if mode == "FULL":
                tmat = rescale_m4(tmat, mat4_to_size(P))
            elif mode == "FIX_SHEAR":
                tmat = rescale_m4(tmat, mat4_to_size_fix_shear(P))
            elif mode == "ALIGNED":
                post = mat4_to_size_fix_shear(P)
        if mode == "AVERAGE":
            factor = cbrt_abs(det3(P))
            tmat = rescale_m4(tmat, np.broadcast_to(factor[..., None], (*factor.shape, 3)))
        rotscale = matmul(tmat, offs)
        if mode == "FIX_SHEAR":
            rotscale = orthogonalize_m4_stable(rotscale, 1, unit=False)
    if not stack.local_location:
        loc = affine(P[..., :3, :3], mul_v3_m4v3(P, stack.offset_translation))
    elif not full:
        loc = matmul(P, offs)
    else:
        loc = None
    return rotscale, loc, post


@dataclass(frozen=True)
class ParentTransform:
    """Blender's ``BoneParentTransform``: how a bone's local matrix becomes its pose matrix.

    ``rotscale`` and ``loc`` are (..., 4, 4), ``post_scale`` (..., 3), for a batch (...) of parent poses.
    """

    rotscale: np.ndarray
    loc: np.ndarray
    post_scale: np.ndarray

    def apply(self, matrix) -> np.ndarray:
        """(..., 4, 4) ``BKE_bone_parent_transform_apply``: local matrices ``matrix`` (..., 4, 4) as pose
        matrices (the batch dimensions broadcast with the transform's)."""
        matrix = np.asarray(matrix)
        out = self.rotscale @ matrix
        out = with_translation(out, mul_v3_m4v3(self.loc, matrix[..., :3, 3]))
        return rescale_m4(out, self.post_scale)

    def inverted(self) -> ParentTransform:
        """``BKE_bone_parent_transform_invert`` (a zero post-scale inverts to zero)."""
        ok = self.post_scale.real != 0
        post = np.where(ok, 1.0 / np.where(ok, self.post_scale, 1.0), 0.0)
        return ParentTransform(inverse_affine(self.rotscale), inverse_affine(self.loc), post)


def parent_transform(bone: Bone, parent: Bone | None, parent_pose=None) -> ParentTransform:
    """``BKE_bone_parent_transform_calc_from_pchan`` / ``_from_matrices``: the inherit flags applied to the
    parent's pose matrix (..., 4, 4).

    Parameters
    ----------
    bone : Bone
    parent : Bone or None
        The parent's rest data (None for a root bone).
    parent_pose : (..., 4, 4) array_like
        The parent's pose matrix (ignored for a root bone).
    """
    stack = BoneStack.of([bone], [parent])
    lead, (P,) = to_single_stack(None if parent is None else parent_pose)
    rotscale, loc, post = _parent_transform(stack, P)
    rotscale = from_single_stack(rotscale, lead)
    loc = rotscale if loc is None else from_single_stack(loc, lead)
    k = math.prod(lead)
    post = np.ones((*lead, 3)) if post is None else np.broadcast_to(post[0], (k, 3)).reshape(*lead, 3)
    return ParentTransform(rotscale, loc, post)


def bone_to_pose(bone: Bone, parent: Bone | None, parent_pose, local) -> np.ndarray:
    """(..., 4, 4) ``BKE_armature_mat_bone_to_pose``: a local matrix ``local`` (..., 4, 4) as a pose matrix,
    under the parent's pose matrix ``parent_pose`` (..., 4, 4) (ignored for a root bone); the batch
    dimensions broadcast."""
    stack = BoneStack.of([bone], [parent])
    lead, (P, L) = to_single_stack(None if parent is None else parent_pose, local)
    return from_single_stack(Parenting(stack, P).to_pose(L), lead)


def pose_to_bone(bone: Bone, parent: Bone | None, parent_pose, pose) -> np.ndarray:
    """(..., 4, 4) ``BKE_armature_mat_pose_to_bone``: a pose matrix ``pose`` (..., 4, 4) as a local matrix,
    under the parent's pose matrix ``parent_pose`` (..., 4, 4) (ignored for a root bone); the batch
    dimensions broadcast."""
    stack = BoneStack.of([bone], [parent])
    lead, (P, M) = to_single_stack(None if parent is None else parent_pose, pose)
    return from_single_stack(Parenting(stack, P).to_local(M), lead)
