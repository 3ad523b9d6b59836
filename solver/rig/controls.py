"""Production rigs posed through their controls: Rigify and its kind, exactly as Blender evaluates them.

An animator's rig is not a tree of deform bones to rotate. Its deform bones (Rigify's ``DEF-``) follow
mechanism bones (``ORG-``, ``MCH-``) through constraints, which follow the controls the animator keys
(``f_index.01.L``, ``hand_ik.L``); deform bones may be B-Bones bent by their neighbours; drivers and IK
move the body above the hand. This module solves a hand on such a rig:

* **The hand, not the body.** The solved part starts at a *hand root* bone (by default the wrist: the
  deform bone where the chains under the contacts meet). The *root control*, the control that moves the
  wrist (Rigify: ``hand_ik.L`` with the arm in IK, ``hand_fk.L`` in FK), moves rigidly by six DOFs
  (``θ[:6]``: its three location channels and a rotation vector; its locked channels stay locked).
  Every bone neither it nor a finger control leads to is input, read from Blender's evaluated pose
  whatever drives it (IK, drivers, constraints); bones between the root control and the hand root that
  cannot be evaluated (an IK arm) are taken to follow the root control rigidly.
* **Controls are the variables.** Every other DOF is a rotation of a *finger control*: the nearest
  control above each deform bone under the hand root (``θ[6 + 3(c - 1) + k]``: Euler angles in the
  control's order; quaternion and axis-angle controls use the Euler order farthest from gimbal lock at
  the start pose and are converted back on the way out). Masters, tweaks and mechanism bones keep their
  channels and are evaluated.
* **Exact.** Between the variables and the deform bones, every bone is posed the way Blender's
  ``BKE_pose_where_is_bone`` does (parenting with its inherit flags, constraints in their spaces with
  influence, :mod:`.bones`, :mod:`.constraints`), and B-Bones deform by their segments (:mod:`.bbone`);
  what cannot be modelled exactly and affects the solved bones is a :class:`Blocker`, never guessed.
  Derivatives of the skinning matrices are exact, by complex-step differentiation (:mod:`.analytic`).

:class:`solver.rig.control_rig.ControlRig` then poses the plan: it stands where :class:`solver.Rig` stands for
:class:`solver.SkinnedMesh` and :class:`solver.ContactIK`, with weights per deform bone and DOFs as above.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import SolverError
from . import bbone, bones

#: A constraint whose result replaces the owner's whole transform (its parent and channels no longer
#: matter) when it is one of these types in one of these owner spaces, mixed by REPLACE at influence 1.
REPLACING = {"COPY_TRANSFORMS"}
REPLACING_SPACES = {"WORLD", "POSE", "CUSTOM"}


@dataclass(frozen=True)
class DriverInput:
    """What a driver on a bone's channels reads of another bone: its ``pose`` (transforms in world or pose
    space) or its ``channel`` values (local-space transforms, or properties such as ``scale``)."""

    bone: str
    kind: str  # "pose" or "channel"


@dataclass(frozen=True, eq=False)
class PoseBone:
    """One bone of an armature as Blender evaluated it, with everything needed to evaluate it again.

    Attributes
    ----------
    bone : solver.rig.bones.Bone
        Rest data and flags (its ``parent`` names the parent bone).
    matrix : (4, 4)
        Blender's evaluated pose matrix (``pose_bone.matrix``), armature space: the value of this bone
        whenever the solved variables do not reach it.
    location, scale : (3,)
        The evaluated channel values (animation and drivers applied).
    rotation : (3,) or (4,)
        The evaluated rotation in the bone's rotation mode (Euler angles, quaternion w x y z, or axis-angle
        angle x y z).
    constraints : tuple of solver.rig.constraints.Constraint
        Active constraints in stack order.
    bbone : solver.rig.bbone.BBone or None
        The B-Bone shape of a deforming bone with more than one segment.
    deform : bool
    lock_location, lock_rotation : (3,) bool
        Blender's transform locks (a bone with every rotation locked is not a control).
    lower, upper : (3,) or None
        Rotation limits of an Euler bone (local Limit Rotation constraints, IK limits), radians.
    drivers : tuple of DriverInput
        What the drivers of this bone's channels read.
    moved_by_ik : tuple of str
        Owners of IK constraints whose chains include this bone (their targets move it).
    ik_targets : tuple of str
        The bones those IK constraints aim at.
    """

    bone: bones.Bone
    matrix: np.ndarray
    location: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotation: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    constraints: tuple = ()
    bbone: bbone.BBone | None = None
    deform: bool = False
    lock_location: tuple[bool, bool, bool] = (False, False, False)
    lock_rotation: tuple[bool, bool, bool] = (False, False, False)
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    drivers: tuple[DriverInput, ...] = ()
    moved_by_ik: tuple[str, ...] = ()
    ik_targets: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.bone.name

    @property
    def parent(self) -> str | None:
        return self.bone.parent

    @property
    def is_control(self) -> bool:
        """Whether an animator can turn it: some rotation channel is unlocked."""
        return not all(self.lock_rotation)

    @cached_property
    def local(self) -> np.ndarray:
        """(4, 4) the channel matrix of the evaluated channels (Blender's ``chan_mat``)."""
        rotation = bones.rotation_matrix(self.bone.rotation_mode, self.rotation)
        return bones.channel_matrix(self.location, rotation, self.scale)

    @cached_property
    def cut(self) -> int:
        """Index of the first constraint after the last one that replaces the whole transform (0: none)."""
        last = 0
        for i, c in enumerate(self.constraints):
            if (
                c.type in REPLACING
                and c.owner_space in REPLACING_SPACES
                and c.get("mix_mode") == "REPLACE"
                and c.influence >= 1.0
            ):
                last = i + 1
        return last

    def pose_inputs(self) -> set[str]:
        """The bones whose poses this bone's pose depends on (its parent, its constraints' targets, what
        its drivers and IK chains read), leaving out what a replacing constraint overrides."""
        used = self.constraints[max(self.cut - 1, 0) :]
        inputs = {t.subtarget for c in used for t in c.targets if t.subtarget}
        inputs |= {c.space_subtarget for c in used if c.space_subtarget}
        after = self.constraints[self.cut :]
        needs_parent = (
            not self.cut
            or self.bone.use_connect
            or any(c.owner_space not in {"WORLD", "POSE", "CUSTOM"} for c in after)
        )
        if self.parent and needs_parent:
            inputs.add(self.parent)
        inputs |= {d.bone for d in self.drivers if d.kind == "pose"}
        inputs |= set(self.ik_targets)
        return inputs


def handles(b: bbone.BBone) -> list[str]:
    """The bones whose poses bend a B-Bone: its handles, and their parents where their scale is read."""
    return [n for n in (*b.handle_names, *b.handle_parent_names) if n]


@dataclass(frozen=True)
class Blocker:
    """Something that moves a solved bone in a way contact IK cannot reproduce, and what to do."""

    bone: str
    reason: str

    def __str__(self) -> str:
        return f"{self.bone}: {self.reason}"


class Armature:
    """All bones of an armature as Blender evaluated them, and the analysis that picks what to solve.

    Parameters
    ----------
    pose_bones : sequence of PoseBone
    world : (4, 4)
        The armature object's matrix_world (constraints in world space need it).
    name : str
        For messages.
    """

    def __init__(self, pose_bones: Sequence[PoseBone], world=None, name: str = "armature"):
        self.name = name
        self.bones: dict[str, PoseBone] = {}
        for b in pose_bones:
            if b.name in self.bones:
                raise SolverError(f"'{name}' has two bones called {b.name!r}")
            self.bones[b.name] = b
        missing = sorted({b.parent for b in pose_bones if b.parent and b.parent not in self.bones})
        if missing:
            raise SolverError(f"bones of '{name}' name parents it does not have: {', '.join(missing)}")
        self.world = np.eye(4) if world is None else np.array(world, dtype=np.float64)
        # Pose dependencies and their reverse (who reads whom). A target read in its local space is read
        # through its parent's pose too.
        self.inputs: dict[str, set[str]] = {}
        for b in pose_bones:
            known = {i for i in b.pose_inputs() if i in self.bones}
            for c in b.constraints[max(b.cut - 1, 0) :]:
                if c.target_space in ("LOCAL", "LOCAL_OWNER_ORIENT"):
                    known |= {self.bones[t.subtarget].parent for t in c.targets if t.subtarget in self.bones}
            self.inputs[b.name] = known - {None}
        self.readers: dict[str, set[str]] = {n: set() for n in self.bones}
        for n, ins in self.inputs.items():
            for i in ins:
                self.readers[i].add(n)

    def __getitem__(self, name: str) -> PoseBone:
        try:
            return self.bones[name]
        except KeyError:
            raise SolverError(f"'{self.name}' has no bone called {name!r}") from None

    def upstream(self, names) -> set[str]:
        """Every bone the given bones' poses depend on, transitively (the given ones excluded)."""
        return self._closure(names, self.inputs)

    def downstream(self, names) -> set[str]:
        """Every bone whose pose depends on the given bones, transitively (the given ones excluded)."""
        return self._closure(names, self.readers)

    @staticmethod
    def _closure(names, edges) -> set[str]:
        seen: set[str] = set()
        queue = deque(names)
        while queue:
            for nxt in edges.get(queue.popleft(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    queue.append(nxt)
        return seen - set(names)

    def parent_chain(self, name: str) -> list[str]:
        """The bone and its parents, nearest first."""
        chain = []
        while name is not None:
            chain.append(name)
            name = self.bones[name].parent
        return chain

    def deform_parent(self, name: str) -> str | None:
        """The nearest deforming bone among the bone's parents."""
        for up in self.parent_chain(name)[1:]:
            if self.bones[up].deform:
                return up
        return None

    # ------------------------------------------------------------------ choosing what to solve

    def hand_root(self, contact_bones: Sequence[str]) -> str:
        """The wrist for contacts weighted to ``contact_bones`` (deform bones): the deform bone where
        deforming chains branch nearest to them. That is their lowest common deform ancestor when chains
        branch there (contacts on several fingers); else, below it, the first branching bone on its single
        chain (contacts on the fingers and on a forearm stub above the wrist); else, above it, the first
        branching ancestor (contacts on one finger); else the topmost deform bone."""
        contact = [n for n in dict.fromkeys(contact_bones) if n in self.bones]
        if not contact:
            raise SolverError("no contact point is weighted to a deform bone of the armature")
        chains = [[n] + [u for u in self.parent_chain(n)[1:] if self.bones[u].deform] for n in contact]
        common = [n for n in chains[0] if all(n in c for c in chains[1:])]
        if not common:
            raise SolverError(
                f"the contacts' bones of '{self.name}' ({', '.join(contact[:5])}) share no deforming "
                "ancestor; pick the hand root bone by hand"
            )
        children: dict[str, list[str]] = {}
        for b in self.bones.values():
            up = self.deform_parent(b.name) if b.deform else None
            if up is not None:
                children.setdefault(up, []).append(b.name)
        node = common[0]
        while len(children.get(node, ())) == 1:
            node = children[node][0]
        if len(children.get(node, ())) >= 2:
            return node
        return next((n for n in common if len(children.get(n, ())) >= 2), common[-1])

    def root_control(self, hand_root: str, skin_bones: Sequence[str] = ()) -> str | None:
        """The control that moves the wrist: from the hand root, the nearest bone it depends on (following
        replacing constraints to their targets, else parents) that has all three rotations free; then up to
        its parent if that is a plain deforming bone of the skin (``skin_bones``) at the top of the
        armature, so that a forearm stub modelled with the hand moves with it. A forearm hanging from an
        upper arm keeps its pose (moving it would open the elbow), as does everything above it in a body.
        None if there is none."""
        skin = set(skin_bones)
        name, seen = hand_root, set()
        while any(self.bones[name].lock_rotation):
            seen.add(name)
            name = self._lead(self.bones[name])
            if name is None or name in seen:
                return None
        up = self.bones[name].parent
        if up is None or up not in skin:
            return name
        p = self.bones[up]
        if p.parent is not None or p.constraints or any(p.lock_rotation) or not p.deform:
            return name
        return up

    def _lead(self, b: PoseBone) -> str | None:
        """The bone that mostly decides ``b``'s place: the target of its last replacing constraint, or
        else its parent."""
        if b.cut:
            targets = [t.subtarget for t in b.constraints[b.cut - 1].targets if t.subtarget in self.bones]
            if targets:
                return targets[0]
        return b.parent

    def finger_controls(self, hand_root: str, deform: Sequence[str], root: str | None) -> list[str]:
        """The controls directly above the deform bones from the hand root down: searching up from each,
        the first controls met on every path (a path ends there), never going above the hand root or
        into the root control. The hand root itself is one when it is a control (a plain rig's wrist)."""
        fixed = {root} | self.upstream([root]) if root is not None else set()
        above = self.upstream([hand_root]) | {hand_root} | fixed
        below = self.downstream([hand_root]) | {hand_root}
        found: dict[str, None] = {}
        for start in deform:
            if start not in below:
                continue
            queue, seen = deque([start]), {start}
            while queue:
                name = queue.popleft()
                if self.bones[name].is_control and name not in fixed:
                    found[name] = None
                    continue
                for up in self.inputs[name] - above - seen:
                    seen.add(up)
                    queue.append(up)
        order = list(self.bones)
        return sorted(found, key=order.index)

    def plan(
        self,
        deform: Sequence[str],
        contact_bones: Sequence[str] = (),
        hand_root: str | None = None,
        root: str | None = "auto",
        skin_bones: Sequence[str] | None = None,
    ) -> Plan:
        """What a solve of a skin weighted to ``deform`` bones would pose, and what blocks it.

        Parameters
        ----------
        deform : sequence of str
            The deform bones weighting the skin (the columns of its weights).
        contact_bones : sequence of str
            The deform bones weighting the contact points (to find the wrist); default ``deform``.
        hand_root : str, optional
            The wrist bone (default: :meth:`hand_root`).
        root : str or None
            The root control; ``"auto"`` (default) finds it (:meth:`root_control`), None leaves the hand
            root where it is (fingers only).
        skin_bones : sequence of str, optional
            The deform bones weighting the skin noticeably (default ``deform``).
        """
        for n in deform:
            self[n]
        hand_root = hand_root if hand_root is not None else self.hand_root(contact_bones or deform)
        self[hand_root]
        if root == "auto":
            root = self.root_control(hand_root, deform if skin_bones is None else skin_bones)
        elif root is not None:
            self[root]
            if root != hand_root and root not in self.upstream([hand_root]):
                raise SolverError(
                    f"the root control {root!r} does not move the hand root {hand_root!r} of '{self.name}'"
                )
        fingers = self.finger_controls(hand_root, deform, root)
        sources = set(fingers) | ({root} if root else set())
        moved = self.downstream(sources) | sources
        arm = (self.upstream([hand_root]) | {hand_root}) & moved
        needed, rigid, blockers = self._trace(deform, moved, arm, set(fingers), root)
        return Plan(
            armature=self,
            deform=tuple(deform),
            hand_root=hand_root,
            root=root,
            controls=tuple(fingers),
            needed=frozenset(needed),
            rigid=frozenset(rigid),
            blockers=tuple(blockers),
        )

    def _trace(self, deform, moved, arm, fingers, root) -> tuple[set[str], set[str], list[Blocker]]:
        """Walk up from the deform bones (and their B-Bone handles) through the bones the solve moves.

        Returns the bones to evaluate as Blender does; the bones that move rigidly with the root control
        (the root control itself, and bones between it and the hand root that cannot be evaluated, such
        as an IK arm, which is taken to follow the hand); and what blocks the solve (a bone under the
        hand root that cannot be evaluated).
        """
        variables = fingers | ({root} if root else set())
        needed: set[str] = set()
        rigid: set[str] = set()
        blockers: list[Blocker] = []
        queue = deque(deform)
        for n in deform:
            b = self.bones[n].bbone
            if b is not None and (n in moved or any(h in moved for h in handles(b))):
                queue.extend(handles(b))
                why = b.unsupported()
                if why:
                    blockers.append(Blocker(n, f"B-Bone {why}"))
        seen: set[str] = set()
        while queue:
            n = queue.popleft()
            if n in seen or n not in moved:
                continue
            seen.add(n)
            if n == root:
                rigid.add(n)
                continue
            b = self.bones[n]
            why = self._not_modelled(b, moved, variables)
            if not why:
                needed.add(n)
                queue.extend(self.inputs[n])
            elif n in arm:
                rigid.add(n)
            else:
                blockers.extend(Blocker(n, w) for w in why)

        return needed, rigid, blockers

    def _not_modelled(self, b: PoseBone, moved, variables) -> list[str]:
        """Why Blender's pose of ``b`` cannot be reproduced (when the solve moves its inputs)."""
        why = []
        for c in b.constraints[max(b.cut - 1, 0) :]:
            reason = c.unsupported()
            if reason:
                why.append(f"{reason}; mute it, or pick a hand root above it")
        why += [f"moved by the IK constraint of '{owner}'; turn the chain to FK" for owner in b.moved_by_ik]
        for d in b.drivers:
            if (d.kind == "pose" and d.bone in moved) or (d.kind == "channel" and d.bone in variables):
                why.append(f"a driver reads what '{d.bone}' does, which the solve changes")
        return why


@dataclass(frozen=True, eq=False)
class Plan:
    """What a solve poses: the hand root, the root control, the finger controls, what blocks it.

    ``needed`` are the bones evaluated as Blender does; ``rigid`` the bones that move rigidly with the
    root control (the control itself, and bones between it and the hand root that cannot be evaluated,
    such as an IK arm: they are taken to follow the hand). Every other bone keeps Blender's pose.
    """

    armature: Armature
    deform: tuple[str, ...]
    hand_root: str
    root: str | None
    controls: tuple[str, ...]
    needed: frozenset
    rigid: frozenset
    blockers: tuple[Blocker, ...]

    @property
    def approximated(self) -> tuple[str, ...]:
        """The bones taken to follow the hand rigidly that Blender moves otherwise (IK chains)."""
        return tuple(sorted(self.rigid - {self.root}))

    @property
    def ok(self) -> bool:
        return not self.blockers

    def describe_blockers(self, limit: int = 6) -> str:
        shown = "; ".join(str(b) for b in self.blockers[:limit])
        more = f"; … ({len(self.blockers)} in all)" if len(self.blockers) > limit else ""
        return shown + more


__all__ = ["Armature", "Blocker", "DriverInput", "Plan", "PoseBone", "handles"]
