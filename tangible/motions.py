"""Joint motions that drive the simulated device's sensors (:class:`~tangible.simulator.Simulator`).

A motion is any callable ``motion(t) -> (n, 4)``: the rotation (unit quaternion) of every joint, in
``DeviceTree.joints`` order, at time ``t`` seconds. :class:`RandomMotion` (smooth, seeded, endless) and
:class:`KeyframeMotion` (scripted) also take arrays of times, so the simulator samples them a block of
instants at a time.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from . import rotations as rot
from .errors import DeviceError
from .joint import BEND_LIMIT, joint_rotation

__all__ = ["KeyframeMotion", "Motion", "RandomMotion"]

#: A motion gives the rotation of every joint (in ``DeviceTree.joints`` order) at time t: (n, 4).
Motion = Callable[[float], np.ndarray]


class RandomMotion:
    """Smooth random joint motion: in record order, each twist a sum of three sinusoids plus a drift (the
    rings turn without end) and each bend a sum of three sinusoids, with seeded frequencies and phases,
    as rotations (:func:`tangible.joint.joint_rotation`).

    Parameters
    ----------
    n : int
        Number of joints.
    seed : int
    max_bend : float
        Bound on each hinge angle (radians, below 90°).
    speed : float
        Scales every frequency (1: components between 0.1 and 0.8 Hz).
    """

    def __init__(self, n: int, seed: int = 0, max_bend: float = np.radians(60.0), speed: float = 1.0):
        if not 0 < max_bend < BEND_LIMIT:
            raise DeviceError(f"max_bend must lie in (0, {BEND_LIMIT:.4f}) radians, got {max_bend!r}")
        rng = np.random.default_rng(seed)
        self.n = n
        self._freq = speed * rng.uniform(0.1, 0.8, (n, 4, 3))
        self._phase = rng.uniform(0.0, 2.0 * np.pi, (n, 4, 3))
        amp = rng.dirichlet([2.0, 2.0, 2.0], (n, 4))
        amp[:, 1:3] *= max_bend / np.sqrt(2.0)
        amp[:, [0, 3]] *= np.pi
        self._amp = amp
        self._drift = np.zeros((n, 4))
        self._drift[:, [0, 3]] = speed * rng.uniform(-0.5, 0.5, (n, 2))

    def angles(self, t) -> np.ndarray:
        """(..., n, 4) the joints' angles at time(s) ``t`` (seconds, any shape), record order."""
        t = np.asarray(t, dtype=np.float64)[..., None, None]
        wave = np.sum(self._amp * np.sin(2.0 * np.pi * self._freq * t[..., None] + self._phase), axis=-1)
        return wave + self._drift * t

    def __call__(self, t) -> np.ndarray:
        """(..., n, 4) rotations at time(s) ``t``."""
        return joint_rotation(self.angles(t))


class KeyframeMotion:
    """Scripted motion: rotations slerped between keys, held before the first and after the last.

    Parameters
    ----------
    times : (k,) array_like
        Increasing key times (seconds).
    rotations : (k, n, 4) array_like
        Joint rotations (quaternions) at the keys.
    """

    def __init__(self, times, rotations):
        self.times = np.asarray(times, dtype=np.float64).reshape(-1)
        self.rotations = np.asarray(rotations, dtype=np.float64)
        r = self.rotations
        if r.ndim != 3 or r.shape[0] != self.times.size or r.shape[2] != 4:
            raise DeviceError(f"keyframe rotations must have shape ({self.times.size}, n, 4), got {r.shape}")
        if np.any(np.diff(self.times) <= 0):
            raise DeviceError("keyframe times must increase")

    def __call__(self, t) -> np.ndarray:
        """(..., n, 4) rotations at time(s) ``t`` (seconds, any shape)."""
        t = np.asarray(t, dtype=np.float64)
        last = self.times.size - 1
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, last)
        j = np.minimum(i + 1, last)
        span = np.where(j > i, self.times[j] - self.times[i], 1.0)
        u = np.clip((t - self.times[i]) / span, 0.0, 1.0)[..., None]
        return rot.slerp(self.rotations[i], self.rotations[j], u)
