"""Procedural creatures with sample poses, for tests and benchmarks of the rig reduction.

:func:`creature` builds a quadruped (pelvis root, spine, neck, head, tail, four legs) and, as the bone
budget grows, toes and wings with fingers, like the paper's horse (29 bones), scorpion (62) and dragon
(110). Its sample poses come from a few shared motion modes (gait, neck, tail, wing beat) plus per-bone
noise, so that — as in real rigs — a few bones carry most of the motion (§3.2).
"""

from __future__ import annotations

import numpy as np

from . import rotations as rot
from .errors import RigError
from .skeleton import Skeleton

__all__ = ["creature"]

#: Fewest bones :func:`creature` can build (pelvis, 2 spine, neck, head, 2 tail, four 3-bone legs).
MIN_BONES = 19


class _Builder:
    def __init__(self):
        self.names: list[str] = []
        self.parents: list[int] = []
        self.heads: list[np.ndarray] = []
        self.tails: list[np.ndarray] = []
        self.mode: list[int] = []  # which motion mode drives the bone
        self.gain: list[float] = []  # how strongly

    def bone(self, name, parent, head, tail, mode, gain) -> int:
        self.names.append(name)
        self.parents.append(parent)
        self.heads.append(np.asarray(head, float))
        self.tails.append(np.asarray(tail, float))
        self.mode.append(mode)
        self.gain.append(gain)
        return len(self.names) - 1

    def chain(self, name, parent, start, direction, n, length, mode, gain, curl=0.0) -> list[int]:
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        out, p, head = [], parent, np.asarray(start, float)
        for i in range(n):
            # bend slowly towards -z (gravity) by `curl` per bone
            d = d + np.array([0.0, 0.0, -curl])
            d /= np.linalg.norm(d)
            tail = head + length * d
            p = self.bone(f"{name}.{i:02d}", p, head, tail, mode, gain * (0.85**i))
            out.append(p)
            head = tail
        return out


def creature(n_bones: int, n_poses: int = 8, seed: int = 0) -> tuple[Skeleton, np.ndarray]:
    """A creature with exactly ``n_bones`` bones and ``n_poses`` sample poses.

    Parameters
    ----------
    n_bones : int
        At least :data:`MIN_BONES`; toes appear from 40 bones, wings from 60.
    n_poses : int
    seed : int
        Seeds the pose generator (the skeleton depends only on ``n_bones``).

    Returns
    -------
    skeleton : Skeleton
        Weights are the default length proxy.
    poses : (n_poses, n_bones, 4)
        Local rotations (quaternions); the root's is the identity.
    """
    if n_bones < MIN_BONES:
        raise RigError(f"a creature needs at least {MIN_BONES} bones, got {n_bones}")
    toes = n_bones >= 40
    wings = n_bones >= 60
    B = _Builder()
    GAIT, NECK, TAIL, WING, BODY = range(5)
    pelvis = B.bone("pelvis", -1, [0, 0, 1.0], [0, 0.25, 1.0], BODY, 0.0)
    spine = B.chain("spine", pelvis, [0, 0.25, 1.0], [0, 1, 0.05], 3 if n_bones >= 30 else 2, 0.3, BODY, 0.25)
    n_neck = 3 if n_bones >= 30 else 1
    neck = B.chain("neck", spine[-1], B.tails[spine[-1]], [0, 0.6, 0.8], n_neck, 0.18, NECK, 0.5)
    B.bone("head", neck[-1], B.tails[neck[-1]], B.tails[neck[-1]] + [0, 0.3, -0.05], NECK, 0.4)
    legs = []
    for side, x in (("L", 0.2), ("R", -0.2)):
        for end, root in (("hind", pelvis), ("fore", spine[-1])):
            start = B.heads[root] + [x, 0.0, 0.0] if end == "hind" else B.tails[root] + [x, 0.0, 0.0]
            legs.append(B.chain(f"{end}leg.{side}", root, start, [0, 0.1, -1], 3, 0.3, GAIT, 0.7))
    if wings:
        for side, x in (("L", 1.0), ("R", -1.0)):
            arm = B.chain(f"wing.{side}", spine[-1], B.tails[spine[-1]], [x, -0.2, 0.4], 3, 0.35, WING, 0.8)
            for f in range(3):
                direction = [x, -0.4 * f, 0.3 - 0.4 * f]
                B.chain(f"finger{f}.{side}", arm[-1], B.tails[arm[-1]], direction, 2, 0.3, WING, 0.3)
    if toes:
        for leg in legs:
            foot = leg[-1]
            for t in range(3):
                direction = [0.2 * (t - 1), 1.0, -0.2]
                B.chain(f"{B.names[foot]}.toe{t}", foot, B.tails[foot], direction, 1, 0.08, GAIT, 0.15)
    remaining = n_bones - len(B.names)
    if remaining < 2:
        raise RigError(f"cannot build a {n_bones}-bone creature with a tail")
    step = min(0.25, 2.5 / remaining)
    B.chain("tail", pelvis, [0, 0, 1.0], [0, -1, 0.1], remaining, step, TAIL, 0.4, curl=0.02)
    skeleton = Skeleton.from_heads_tails(B.names, B.parents, np.array(B.heads), np.array(B.tails))

    rng = np.random.default_rng(seed)
    mode = np.array(B.mode)
    gain = np.array(B.gain)
    # Each mode is a 2-D latent (amplitude, phase-like); each bone maps its mode's latent to a rotation
    # vector through a fixed random matrix, so bones of a chain move together.
    latent = rng.normal(size=(n_poses, 5, 2))
    maps = np.random.default_rng(1000 + n_bones).normal(size=(n_bones, 3, 2)) * 0.6
    maps[:, 1] *= 0.3  # less twist about the bone than bending
    v = np.einsum("bij,pbj->pbi", maps, latent[:, mode]) * gain[None, :, None]
    v += 0.04 * rng.normal(size=v.shape) * (gain[None, :, None] > 0)
    poses = rot.from_rotvec(v)
    poses[:, pelvis] = rot.IDENTITY
    return skeleton, poses
