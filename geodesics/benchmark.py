"""Timings of the geodesic core, side by side with the peers the paper's authors used.

:func:`run` returns the rows; the ``contact-edit bench geodesics`` command prints them. Peers that are
not installed (potpourri3d, pygeodesic) are reported as missing rather than failing the run.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .exact import GeodesicField
from .maps import log_map
from .points import SurfacePoints
from .primitives import torus
from .tangent import tangent_from_3d, tangent_to_3d
from .trace import exp_map


@dataclass(frozen=True)
class Row:
    """One benchmark line: our median time, the peer's (if any), and what the numbers mean."""

    task: str
    ours: float
    peer: float | None = None
    peer_name: str = ""
    note: str = ""


#: Untimed runs first: per-mesh precomputation is shared by all queries, and the first runs in a
#: process also pay for the allocator growing its heap; an interactive session is past both.
WARMUP = 3
#: Ours and the peer are timed in this many alternating blocks of runs: a burst of load from other jobs
#: on a shared machine (tens of milliseconds) then slows some runs of both, not every run of one.
BLOCKS = 3


def _median_times(fns: list[Callable[[], object]], repeat: int) -> list[float]:
    """Median seconds of each of ``fns`` over ``repeat`` runs (rounded up to whole blocks) after
    :data:`WARMUP` untimed ones, the runs alternating between them in :data:`BLOCKS` blocks."""
    for fn in fns:
        for _ in range(WARMUP):
            fn()
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(BLOCKS):
        for fn, spent in zip(fns, times, strict=True):
            for _ in range(-(-repeat // BLOCKS)):
                start = time.perf_counter()
                fn()
                spent.append(time.perf_counter() - start)
    return [float(np.median(spent)) for spent in times]


def median_time(fn: Callable[[], object], repeat: int) -> float:
    """Median seconds of ``fn`` over ``repeat`` runs after :data:`WARMUP` untimed ones: the timing every
    benchmark of the libraries (geodesics, solver, tangible) uses."""
    return _median_times([fn], repeat)[0]


def _beside(
    ours: Callable[[], object], peer: Callable[[], object] | None, repeat: int
) -> tuple[float, float | None]:
    """Median seconds of ``ours`` and of ``peer`` (None where there is no peer), timed alternately."""
    if peer is None:
        return median_time(ours, repeat), None
    ours_time, peer_time = _median_times([ours, peer], repeat)
    return ours_time, peer_time


def _random_points(mesh, k, rng) -> SurfacePoints:
    return SurfacePoints(rng.integers(0, mesh.n_faces, k), rng.dirichlet([2.0, 2.0, 2.0], k))


def run(repeat: int = 5, rays: int = 2000, progress: Callable[[str], None] | None = None) -> list[Row]:
    """Run the geodesic benchmarks; ``progress`` receives a line of text before each one."""
    say = progress or (lambda _msg: None)
    mesh = torus(n_major=140, n_minor=72)  # 20,160 faces, with saddle vertices on the inner side
    rng = np.random.default_rng(0)

    say("exp_map")
    rows = [_exp_map_row(mesh, rng, rays, repeat)]
    say("log_map")
    origin = SurfacePoints.from_vertices(mesh, [int(rng.integers(mesh.n_vertices))])
    rows += _log_map_rows(mesh, origin, rng, rays, repeat)
    say("vector heat log map")
    rows += _vector_heat_rows(mesh, origin, repeat)
    say("1M faces")
    rows += _million_faces_rows(rng, rays, repeat)
    say("whole-mesh exact fields")
    rows += _whole_field_rows()
    return rows


def _exp_map_row(mesh, rng, rays: int, repeat: int) -> Row:
    """``rays`` straightest geodesics a tenth of the diameter long, beside potpourri3d's tracer (looped:
    it traces one ray a call), whose end points are checked against ours."""
    diameter = mesh.bounding_diagonal
    origins = _random_points(mesh, rays, rng)
    z = 0.1 * diameter * np.exp(1j * rng.uniform(0, 2 * np.pi, rays))

    def ours():
        return exp_map(mesh, origins, z)

    theirs, peer_name, note = None, "potpourri3d GeodesicTracer (looped)", "not installed"
    try:
        import potpourri3d

        tracer = potpourri3d.GeodesicTracer(mesh.vertices, mesh.faces)
        directions = tangent_to_3d(mesh, origins, z)
        faces, bary = origins.faces, origins.bary

        def theirs():
            return [
                tracer.trace_geodesic_from_face(int(faces[i]), bary[i], directions[i]) for i in range(rays)
            ]

        ends = np.array([p[-1] for p in theirs()])
        gap = np.max(np.linalg.norm(ends - ours().points.positions(mesh), axis=1))
        note = f"end points agree to {gap / diameter:.1e} x diameter"
    except ImportError:
        pass
    task = f"exp_map: {rays} rays, 10% of the diameter long"
    return Row(task, *_beside(ours, theirs, repeat), peer_name, note)


def _log_map_rows(mesh, origin: SurfacePoints, rng, rays: int, repeat: int) -> list[Row]:
    """The exact log map from ``origin`` to ``rays`` targets near it and all over the mesh, beside
    pygeodesic's exact distances (MMP) to the vertices within the same radius."""
    rows = []
    pool = _random_points(mesh, 40 * rays, rng)
    distance = GeodesicField(mesh, origin).query(pool).distances
    for share in (0.25, 1.0):
        radius = share * distance.max()
        targets = pool[np.flatnonzero(distance <= radius)[:rays]]

        def ours(t=targets):
            return log_map(mesh, origin, t)

        theirs, note = None, "not installed"
        try:
            import pygeodesic.geodesic as pygeodesic

            solver = pygeodesic.PyGeodesicAlgorithmExact(mesh.vertices, mesh.faces)
            source = origin.vertex_ids(mesh)
            nearby = np.flatnonzero(
                GeodesicField(mesh, origin, max_distance=radius).vertex_distance <= radius
            )

            def theirs(s=solver, v=source, n=nearby, r=radius):
                return s.geodesicDistances(v, n, r)

            note = "peer: distances at vertices only, no directions"
        except ImportError:
            pass
        where = "over the whole mesh" if share == 1.0 else f"within {share:.0%} of the farthest distance"
        rows.append(
            Row(
                f"log_map (exact): {len(targets)} targets {where}",
                *_beside(ours, theirs, repeat),
                "pygeodesic MMP (Kirsanov)",
                note,
            )
        )
    return rows


def _vector_heat_rows(mesh, origin: SurfacePoints, repeat: int) -> list[Row]:
    """For contrast, potpourri3d's approximate log map at every vertex (the vector heat method) with its
    distance error against the exact distances; no row without potpourri3d."""
    diameter = mesh.bounding_diagonal
    try:
        import potpourri3d

        heat = potpourri3d.MeshVectorHeatSolver(mesh.vertices, mesh.faces)
        vertex = int(origin.vertex_ids(mesh)[0])
        approx = heat.compute_log_map(vertex)
        exact = GeodesicField(mesh, origin).vertex_distance
        error = np.abs(np.linalg.norm(approx, axis=1) - exact)
        peer = median_time(lambda: heat.compute_log_map(vertex), repeat)
        return [
            Row(
                "for contrast: approximate log map at all vertices",
                np.nan,
                peer,
                "potpourri3d vector heat method",
                f"its distance error: median {np.median(error) / diameter:.1e}, "
                f"max {error.max() / diameter:.1e} x diameter",
            )
        ]
    except ImportError:
        return []


def _million_faces_rows(rng, rays: int, repeat: int) -> list[Row]:
    """A torus of a million faces: building and validating it (one run), then ``rays`` straightest
    geodesics on it, with the peak memory of both."""
    tracemalloc.start()
    start = time.perf_counter()
    big = torus(n_major=1000, n_minor=500)
    built = time.perf_counter() - start
    origins = _random_points(big, rays, rng)
    z = 0.1 * big.bounding_diagonal * np.exp(1j * rng.uniform(0, 2 * np.pi, rays))
    exp_map(big, origins, z)
    traced = median_time(lambda: exp_map(big, origins, z), repeat)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return [
        Row(f"1M faces: build and validate ({big.n_faces:,} faces)", built, note="one run"),
        Row(
            f"1M faces: exp_map {rays} rays",
            traced,
            note=f"peak memory of mesh and tracing: {peak / 2**30:.2f} GiB",
        ),
    ]


#: Tori (n_major, n_minor) of about 80k, 320k and 1M faces, shaped as the 1M-face torus above.
WHOLE_FIELD_TORI = ((284, 142), (566, 283), (1000, 500))


def _whole_field_rows() -> list[Row]:
    """A whole-mesh exact field (no targets, no limit) from one vertex of each of
    :data:`WHOLE_FIELD_TORI`: one run each, in a fresh process so that its peak resident memory is its
    own; beside pygeodesic's exact distances at every vertex on the first."""
    rows = []
    for i, (n_major, n_minor) in enumerate(WHOLE_FIELD_TORI):
        ours = _in_fresh_process("ours", n_major, n_minor)
        peer = _in_fresh_process("pygeodesic", n_major, n_minor) if i == 0 else None
        note = (
            f"peak resident {ours['peak'] / 2**30:.2f} GiB (mesh alone {ours['mesh'] / 2**30:.2f}); "
            f"{ours['windows'] / ours['faces']:.0f} windows a face, "
            f"{ours['records'] / ours['windows']:.0%} of them with a whole record"
        )
        if peer is not None and "error" not in peer:
            note += f"; pygeodesic: peak resident {peer['peak'] / 2**30:.2f} GiB, distances at vertices only"
        rows.append(
            Row(
                f"whole-mesh exact field, {ours['faces']:,} faces",
                ours["seconds"],
                None if peer is None or "error" in peer else peer["seconds"],
                "pygeodesic MMP (Kirsanov)" if peer is not None else "",
                f"one run; {note}",
            )
        )
    return rows


def _in_fresh_process(who: str, n_major: int, n_minor: int) -> dict:
    """Run :func:`_whole_field` in a new Python process and return what it reports."""
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]))
    code = f"from geodesics.benchmark import _whole_field; _whole_field({who!r}, {n_major}, {n_minor})"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    return json.loads(done.stdout.splitlines()[-1])


def _resident(field: str) -> int:
    """This process's resident memory (``VmRSS``) or its peak (``VmHWM``) in bytes, from /proc."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _whole_field(who: str, n_major: int, n_minor: int) -> None:
    """Child process of :func:`_in_fresh_process`: build the torus, compute one whole-mesh field (ours,
    or pygeodesic's distances at every vertex) and print seconds and memory as a JSON line."""
    mesh = torus(n_major=n_major, n_minor=n_minor)
    out = {"faces": mesh.n_faces, "mesh": _resident("VmRSS")}
    start = time.perf_counter()
    if who == "ours":
        field = GeodesicField(mesh, SurfacePoints.from_vertices(mesh, [0]))
        out.update(windows=int(field.W.size), records=int(field.W.rec.size))
    else:
        try:
            import pygeodesic.geodesic as pygeodesic
        except ImportError:
            print(json.dumps({"error": "not installed"}))
            return
        pygeodesic.PyGeodesicAlgorithmExact(mesh.vertices, mesh.faces).geodesicDistances(np.array([0]), None)
    out.update(seconds=time.perf_counter() - start, peak=_resident("VmHWM"))
    print(json.dumps(out))


def run_contacts(repeat: int = 5, progress: Callable[[str], None] | None = None) -> list[Row]:
    """Time the contact model: a 2,000-point patch on a 20k-face mesh (parameterize, transfer and the
    interactive edits) and a bulk atlas transfer of 100,000 contacts."""
    from .atlas import ContactAtlas
    from .axis import Axis
    from .default_axes import farthest_pair_axis, medial_axis
    from .patch import ContactPatch
    from .primitives import icosphere, scan_like_torus

    say = progress or (lambda _msg: None)
    rows: list[Row] = []
    mesh = torus(n_major=140, n_minor=72)
    rng = np.random.default_rng(1)
    pool = _random_points(mesh, 400_000, rng)
    centre = SurfacePoints.nearest(mesh, [[1.0, 0.0, 0.35]])
    near = np.argsort(GeodesicField(mesh, centre, max_distance=0.6).query(pool).distances)[:2000]
    points = pool[near]

    say("parameterize")
    axis = farthest_pair_axis(mesh, points)
    ours = median_time(lambda: ContactPatch(mesh, points, axis), repeat)
    rows.append(Row(f"parameterize a {len(points)}-point patch ({len(axis)} axis points, exact)", ours))
    ready = median_time(lambda: ContactPatch(mesh, points, farthest_pair_axis(mesh, points)), repeat)
    rows.append(Row("paint -> patch ready (default axis + parameterization)", ready))
    medial = median_time(lambda: ContactPatch(mesh, points, medial_axis(mesh, points)), repeat)
    rows.append(Row(f"paint -> patch ready (medial axis, {len(medial_axis(mesh, points))} points)", medial))
    patch = ContactPatch(mesh, points, axis)

    say("edits")
    step = mesh.mean_edge_length
    drag = SurfacePoints.nearest(mesh, axis.start.positions(mesh) + np.array([0.0, 0.0, 2 * step]))
    rows.append(
        Row(
            "translate by a mouse step (two edge lengths)",
            median_time(lambda: patch.translate(drag), repeat),
        )
    )
    rows.append(Row("rotate", median_time(lambda: patch.rotate(0.1), repeat)))
    rows.append(
        Row("bend at the middle axis point", median_time(lambda: patch.bend(len(axis) // 2, 0.2), repeat))
    )
    sphere = icosphere(5, radius=1.5)
    start = SurfacePoints.nearest(sphere, [[0.0, 0.0, 1.5]])
    rows.append(Row(
        f"transfer onto another 20k-face mesh (icosphere, {sphere.n_faces} faces)",
        median_time(lambda: patch.transfer(sphere, start, 1.0), repeat),
    ))  # fmt: skip

    say("atlas")
    count = 100_000
    spread = GeodesicField(mesh, centre, max_distance=1.5).query(pool).distances
    contacts = pool[np.argsort(spread)[:count]]  # the 100,000 nearest: the "hand" around the curves
    ends = [
        ((1.0, 0.0, 0.35), (0.8, 0.6, 0.3)),
        ((1.0, 0.0, -0.35), (0.8, -0.6, -0.3)),
        ((1.3, 0.2, 0.0), (1.1, 0.8, 0.0)),
    ]
    curves = {
        f"curve {i}": Axis.between(mesh, SurfacePoints.nearest(mesh, [a]), SurfacePoints.nearest(mesh, [b]))
        for i, (a, b) in enumerate(ends)
    }
    atlas = ContactAtlas(mesh, curves)
    target = scan_like_torus(10_070, seed=3)  # another triangulation of the same torus, ~20k faces
    placements = {}
    for name, curve in curves.items():
        where = SurfacePoints.nearest(target, curve.start.positions(mesh))
        placements[name] = (
            where,
            tangent_from_3d(target, where, tangent_to_3d(mesh, curve.start, curve.direction))[0],
        )
    laid = atlas.lay_out(target, placements)
    ours = median_time(
        lambda: atlas.transfer(contacts, laid, radial_scale={"curve 0": 1.2}), max(1, repeat // 2)
    )
    rows.append(Row(f"atlas transfer of {len(contacts):,} contacts (3 curves, onto a scan-like torus)", ours))
    return rows


def format_table(rows: list[Row]) -> str:
    """A plain-text table of the rows, times in milliseconds, with ours/peer ratios."""

    def ms(t):
        return "" if t is None or not np.isfinite(t) else f"{1e3 * t:9.1f} ms"

    lines = [f"{'task':66} {'ours':>12} {'peer':>12} {'ours/peer':>10}  peer / note"]
    for r in rows:
        ratio = f"{r.ours / r.peer:10.2f}" if r.peer and np.isfinite(r.ours) else " " * 10
        who = r.peer_name if r.peer is not None else ""
        detail = "; ".join(x for x in (who, r.note) if x)
        lines.append(f"{r.task:66} {ms(r.ours):>12} {ms(r.peer):>12} {ratio}  {detail}")
    return "\n".join(lines)
