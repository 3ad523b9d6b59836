"""Assembly instructions for a device: a text tree and an SVG picture (no dependencies).

:func:`instructions_text` lists the pieces from the host down, with colours, slots and the bones they
drive. :func:`instructions_svg` draws two panels: the rig's rest pose (seen along its least significant
principal axis) with the driven bones and splitter nodes in their piece colours, and the device itself as
a tree of coloured joints (circles) and splitters (squares) with slot numbers.
"""

from __future__ import annotations

from collections.abc import Mapping
from html import escape

import numpy as np

from .device import PALETTE, DeviceTree, Piece
from .joint import bend_angle, joint_angles
from .reduction import Reduction

__all__ = ["device_text", "instructions_svg", "instructions_text"]

_NAMES = dict(
    zip(
        PALETTE,
        [
            "red",
            "green",
            "blue",
            "orange",
            "purple",
            "cyan",
            "magenta",
            "brown",
            "maroon",
            "navy",
            "olive",
            "teal",
        ],
        strict=True,
    )
)


def colour_name(rgb: tuple[int, int, int]) -> str:
    """A palette colour's name, else ``#rrggbb``."""
    return _NAMES.get(tuple(rgb), "#{:02x}{:02x}{:02x}".format(*rgb))


def _hex(rgb) -> str:
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def _slot_note(piece: Piece) -> str:
    d = piece.splitter.directions
    angles = np.round(np.degrees(np.arctan2(-d[:, 0], d[:, 1]))) + 0.0
    return ", ".join(f"slot {i}: {a:+.0f}°" for i, a in enumerate(angles))


def device_text(device: DeviceTree, labels: Mapping[int, str] | None = None) -> str:
    """The device as an indented tree from the host, one line per piece; ``labels`` adds text per id."""
    labels = labels or {}
    lines = ["host"]

    def walk(pid: int, prefix: str) -> None:
        kids = device.children(pid)
        parent = None if pid == 0 else device[pid]
        for i, p in enumerate(kids):
            last = i == len(kids) - 1
            where = f"slot {p.slot}: " if parent is not None and parent.kind == "splitter" else ""
            what = "joint" if p.kind == "joint" else f"splitter {p.splitter.name} ({_slot_note(p)})"
            extra = f" — {labels[p.id]}" if p.id in labels else ""
            lines.append(
                f"{prefix}{'└── ' if last else '├── '}{where}{what} #{p.id}, {colour_name(p.colour)}{extra}"
            )
            walk(p.id, prefix + ("    " if last else "│   "))

    walk(0, "")
    return "\n".join(lines)


def instructions_text(reduction: Reduction) -> str:
    """Readable assembly instructions for a reduction's device."""
    sk = reduction.skeleton
    labels = {}
    for pid, b in reduction.bones.items():
        piece = reduction.device[pid]
        if piece.kind == "joint":
            bend = np.degrees(float(bend_angle(joint_angles(reduction.rest[pid]))))
            labels[pid] = f"drives bone {sk.names[b]!r} (bent {bend:.0f}° in the rest pose)"
        else:
            labels[pid] = f"at the branching of bone {sk.names[b]!r}"
    n_j, n_s = len(reduction.device.joints), len(reduction.device.splitters)
    head = (
        f"Device for a {sk.n_bones}-bone rig: {n_j} joint{'s' * (n_j != 1)}, "
        f"{n_s} splitter{'s' * (n_s != 1)}. Plug pieces in as shown, from the host down."
    )
    tail = (
        f"Pose error {100 * reduction.relative_error:.1f}% of a rigid device's; "
        f"{len(reduction.pruned)} bone(s) on branches the device leaves out follow by pose interpolation."
    )
    return "\n".join([head, device_text(reduction.device, labels), tail])


def _tree_layout(device: DeviceTree) -> dict[int, tuple[float, int]]:
    pos: dict[int, tuple[float, int]] = {}
    counter = [0.0]

    def place(pid: int, depth: int) -> float:
        kids = device.children(pid)
        xs = [place(c.id, depth + 1) for c in kids]
        if xs:
            x = float(np.mean(xs))
        else:
            x = counter[0]
            counter[0] += 1.0
        pos[pid] = (x, depth)
        return x

    place(0, 0)
    return pos


def instructions_svg(reduction: Reduction, width: int = 960, height: int = 480) -> str:
    """An SVG picture of the device on the rig (left) and as a tree of pieces (right)."""
    sk = reduction.skeleton
    heads, tails = sk.matrix_local[:, :3, 3], sk.rest_tails
    pts = np.concatenate([heads, tails])
    centre = pts.mean(axis=0)
    _, _, Vt = np.linalg.svd(pts - centre, full_matrices=False)
    axes = Vt[:2]
    if np.dot(axes[1], [0.0, 0.0, 1.0]) < 0:  # keep "up" up when the rig has a vertical extent
        axes[1] = -axes[1]
    uv_h, uv_t = (heads - centre) @ axes.T, (tails - centre) @ axes.T
    lo = np.minimum(uv_h.min(0), uv_t.min(0))
    hi = np.maximum(uv_h.max(0), uv_t.max(0))
    half = width / 2
    scale = 0.85 * min(half / max(hi[0] - lo[0], 1e-9), height / max(hi[1] - lo[1], 1e-9))

    def xy(uv):
        mid = (lo + hi) / 2
        return half / 2 + scale * (uv[0] - mid[0]), height / 2 - scale * (uv[1] - mid[1])

    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
        f'<line x1="{half}" y1="10" x2="{half}" y2="{height - 10}" stroke="#ddd"/>',
    ]
    pruned = set(reduction.pruned)
    for b in range(sk.n_bones):
        (x1, y1), (x2, y2) = xy(uv_h[b]), xy(uv_t[b])
        dash = ' stroke-dasharray="3,3"' if b in pruned else ""
        out.append(f'<line x1="{x1:.1f}" y1="{y1:.1f}" x2="{x2:.1f}" y2="{y2:.1f}" stroke="#999"{dash}/>')
    for pid, b in reduction.bones.items():
        piece = reduction.device[pid]
        c = _hex(piece.colour)
        title = f"<title>{escape(piece.kind)} #{pid}: {escape(sk.names[b])}</title>"
        if piece.kind == "joint":
            (x1, y1), (x2, y2) = xy(uv_h[b]), xy(uv_t[b])
            line = f'x1="{x1:.1f}" y1="{y1:.1f}" x2="{x2:.1f}" y2="{y2:.1f}"'
            out.append(f'<line {line} stroke="{c}" stroke-width="4"/>')
            out.append(f'<circle cx="{x1:.1f}" cy="{y1:.1f}" r="6" fill="{c}">{title}</circle>')
        else:  # where the branches start: the mean head of the branching bone's children
            x, y = xy(uv_h[list(sk.children[b])].mean(axis=0))
            out.append(
                f'<rect x="{x - 6:.1f}" y="{y - 6:.1f}" width="12" height="12" fill="{c}">{title}</rect>'
            )
    pos = _tree_layout(reduction.device)
    xs = np.array([p[0] for p in pos.values()])
    depth = max(p[1] for p in pos.values())
    span = max(xs.max() - xs.min(), 1.0)

    def txy(pid):
        x, d = pos[pid]
        return half + 60 + (width / 2 - 120) * (x - xs.min()) / span, 30 + (height - 60) * d / max(depth, 1)

    for p in reduction.device:
        (x1, y1), (x2, y2) = txy(p.parent), txy(p.id)
        out.append(f'<line x1="{x1:.1f}" y1="{y1:.1f}" x2="{x2:.1f}" y2="{y2:.1f}" stroke="#333"/>')
        if p.parent != 0 and reduction.device[p.parent].kind == "splitter":
            out.append(
                f'<text x="{(x1 + x2) / 2 + 4:.1f}" y="{(y1 + y2) / 2:.1f}" fill="#555">{p.slot}</text>'
            )
    x, y = txy(0)
    out.append(f'<rect x="{x - 14:.1f}" y="{y - 8:.1f}" width="28" height="16" fill="#333"/>')
    out.append(f'<text x="{x + 18:.1f}" y="{y + 4:.1f}">host</text>')
    for p in reduction.device:
        x, y = txy(p.id)
        c = _hex(p.colour)
        label = escape(sk.names[reduction.bones[p.id]])
        if p.kind == "joint":
            out.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="10" fill="{c}"/>')
        else:
            out.append(f'<rect x="{x - 10:.1f}" y="{y - 10:.1f}" width="20" height="20" fill="{c}"/>')
            label = f"{escape(p.splitter.name)} @ {label}"
        out.append(f'<text x="{x:.1f}" y="{y + 4:.1f}" fill="white" text-anchor="middle">{p.id}</text>')
        halo = 'stroke="white" stroke-width="3" paint-order="stroke"'
        out.append(
            f'<text x="{x:.1f}" y="{y + 22:.1f}" font-size="9" text-anchor="middle" {halo}>{label}</text>'
        )
    out.append("</svg>")
    return "\n".join(out)
