"""The constraints that clamp the owner's channels: Limit Rotation, Limit Location, Limit Scale
(``rotlimit_evaluate``, ``loclimit_evaluate``, ``sizelimit_evaluate``)."""

from __future__ import annotations

import numpy as np

from ..math_matrix import mat4_to_size, orthogonalize_m4_stable, rescale_m4, with_translation
from ..math_rotation import loc_eulO_size_to_mat4, mat4_to_eulO


def _wrap_angle(angle):
    b = angle * (0.5 / np.pi) + 0.5
    return (b - np.floor(b.real) - 0.5) * (2.0 * np.pi)


def _clamp_angle(angle, lo, hi):
    """``clamp_angle``: ``angle`` clamped into the directed range ``[lo, hi]`` on the circle (``lo``, ``hi``
    floats or arrays broadcasting against ``angle``)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    mn = _wrap_angle(lo - angle)
    mx = _wrap_angle(hi - angle)
    simple = mn.real < mx.real
    clamped = np.where(mn.real > 0, mn, np.where(mx.real < 0, mx, 0.0))
    inside = (mx.real >= 0) | (mn.real <= 0)
    closest = np.where(np.abs(mx.real) < np.abs(mn.real), mx, mn)
    out = angle + np.where(simple, clamped, np.where(inside, 0.0, closest))
    out = np.where(hi <= lo, lo + 0.0 * angle, out)
    return np.where(hi - lo >= 2 * np.pi, angle, out)


def rotlimit_evaluate(cs, cob, tars, ctx):
    """Limit Rotation (``rotlimit_evaluate``): Euler angles clamped per axis (legacy or on the circle)."""
    cob = orthogonalize_m4_stable(cob, 1, unit=False)
    axes = [cs.get(f"use_limit_{c}") for c in "xyz"]
    if not any(axes):
        return cob
    order = cs.order
    loc, size = cob[..., :3, 3], mat4_to_size(cob)
    eul = np.array(mat4_to_eulO(cob, order))
    for a, c in enumerate("xyz"):
        if not axes[a]:
            continue
        lo, hi = cs.get(f"min_{c}"), cs.get(f"max_{c}")
        if cs.get("use_legacy_behavior"):
            e = eul[..., a]
            eul[..., a] = np.where(e.real < lo, lo, np.where(e.real > hi, hi, e))
        else:
            eul[..., a] = _clamp_angle(eul[..., a], lo, hi)
    return loc_eulO_size_to_mat4(loc, eul, size, order)


def loclimit_evaluate(cs, cob, tars, ctx):
    """Limit Location (``loclimit_evaluate``): the location clamped per axis."""
    loc = cob[..., :3, 3]
    components = []
    for a, c in enumerate("xyz"):
        v = loc[..., a]
        if cs.get(f"use_min_{c}"):
            lo = cs.get(f"min_{c}")
            v = np.where(v.real < lo, lo, v)
        if cs.get(f"use_max_{c}"):
            hi = cs.get(f"max_{c}")
            v = np.where(v.real > hi, hi, v)
        components.append(v)
    return with_translation(cob, np.stack(np.broadcast_arrays(*components), -1))


def sizelimit_evaluate(cs, cob, tars, ctx):
    """Limit Scale (``sizelimit_evaluate``): the scale clamped per axis."""
    obsize = mat4_to_size(cob)
    factors = []
    for a, c in enumerate("xyz"):
        s = obsize[..., a]
        if cs.get(f"use_min_{c}"):
            lo = cs.get(f"min_{c}")
            s = np.where(s.real < lo, lo, s)
        if cs.get(f"use_max_{c}"):
            hi = cs.get(f"max_{c}")
            s = np.where(s.real > hi, hi, s)
        ok = obsize[..., a].real != 0
        factors.append(np.where(ok, s / np.where(ok, obsize[..., a], 1.0), 1.0))
    return rescale_m4(cob, np.stack(np.broadcast_arrays(*factors), -1))
