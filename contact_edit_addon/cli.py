"""The ``contact-edit`` command.

Subcommands:

* ``bench geodesics`` — time the geodesic core side by side with potpourri3d and pygeodesic.
* ``bench contacts`` — time the contact model (parameterize, edits, transfer, atlas).
* ``bench solver`` — time contact IK (analytic against finite-difference gradients, NLopt's optimizers
  side by side) and the flex-to-contact grasp.
* ``bench tangible`` — the puppet device's serial link under corruption, pose interpolation per frame,
  and the rig reduction's error against kit size (the paper's Fig. 7).
* ``ablation`` — the contact IK ablation of Contact Edit's Fig. 11 as a table (each term of Eq. 2 removed).
* ``build-extension`` — build the Blender extension zips, with every run-time dependency as wheels.
* ``demo`` — the embedded default job: a procedural hand grasps a mug; saves, renders, summarizes.
* ``pose`` — pose the hand of a saved scene from its contacts and save it to a new file.

``demo`` and ``pose`` need Blender's Python module (``pip install "contact-edit[blender]"``).
"""

from __future__ import annotations

import argparse
import sys


def _progress(what: str) -> None:
    print(f"  {what} ...", file=sys.stderr, flush=True)


def _bench(args: argparse.Namespace) -> int:
    from geodesics import benchmark

    runs = f"median of {args.repeat} runs after {benchmark.WARMUP} untimed ones"
    print(f"contact-edit bench {args.target}: {runs}", flush=True)
    if args.target == "geodesics":
        rows = benchmark.run(repeat=args.repeat, rays=args.rays, progress=_progress)
    elif args.target == "solver":
        from solver import benchmark as solver_benchmark

        print(f"  finite-difference solves: median of min(repeat, {solver_benchmark.FD_RUNS}), no warm-up")
        rows = solver_benchmark.run(repeat=args.repeat, progress=_progress)
    elif args.target == "tangible":
        from tangible import benchmark as tangible_benchmark

        rows = tangible_benchmark.run(repeat=args.repeat, progress=_progress)
        rows += tangible_benchmark.run_reduction_curve(progress=_progress)
    else:
        rows = benchmark.run_contacts(repeat=args.repeat, progress=_progress)
    print(benchmark.format_table(rows))
    return 0


def _ablation(args: argparse.Namespace) -> int:
    from solver import benchmark

    print("contact-edit ablation: each term of Eq. 2 removed in turn, solved from the rest pose", flush=True)
    print(benchmark.format_ablation(benchmark.ablation(progress=_progress)))
    return 0


def _build_extension(args: argparse.Namespace) -> int:
    from pathlib import Path

    from . import build

    platforms = (
        list(build.PLATFORM_TAGS) if args.all_platforms else args.platform or list(build.DEFAULT_PLATFORMS)
    )
    try:
        paths = build.build_extension(Path(args.output), platforms=platforms, progress=_progress)
    except build.BuildError as err:
        print(f"contact-edit build-extension: {err}", file=sys.stderr)
        return 1
    for path in paths:
        print(path)
    return 0


def _blender():
    """Import bpy and register the add-on's classes in it (a script's Blender, not an installed one)."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        print(
            "contact-edit: this command needs Blender's Python module; install it with\n"
            '  pip install "contact-edit[blender]"   (bpy 5.0.1, Python 3.11)',
            file=sys.stderr,
        )
        return None
    import contact_edit_addon

    contact_edit_addon.register()
    return contact_edit_addon


def _demo(args: argparse.Namespace) -> int:
    if _blender() is None:
        return 2
    from . import demo

    result = demo.run(args.out, render=not args.no_render, progress=_progress)
    print(f"contact-edit demo: a procedural human hand grasps a mug ({result.seconds:.1f} s in all)")
    print(f"  patches transferred onto the mug: {result.patches} ({result.contacts} contact points)")
    print(f"  solve: {result.summary}")
    print(f"  scene:    {result.blend}")
    print(f"  contacts: {result.contacts_file}")
    if result.image is not None:
        print(f"  render:   {result.image}")
    return 0


def _pose(args: argparse.Namespace) -> int:
    if _blender() is None:
        return 2
    from geodesics import ContactError
    from solver import SolverError

    from . import batch
    from .bridge import BridgeError

    def bar(done: int, total: int, energy: float) -> None:
        filled = int(30 * min(done, total) / total)
        print(f"\r  solving [{'#' * filled}{'.' * (30 - filled)}] {done}/{total} energy {energy:.4g}",
              end="", file=sys.stderr, flush=True)  # fmt: skip

    try:
        summary = batch.pose_scene(
            args.scene, args.output, hand=args.hand, target=args.object, contacts=args.contacts,
            frame=args.frame, stage=args.stage, overwrite=args.overwrite, remap=args.remap, progress=bar,
        )  # fmt: skip
    except (BridgeError, ContactError, SolverError) as err:
        print(f"\ncontact-edit pose: {err}", file=sys.stderr)
        return 1
    print(file=sys.stderr)
    print(f"contact-edit pose: {summary}")
    print(f"  saved {args.output}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="contact-edit", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    bench = commands.add_parser("bench", help="run a benchmark and print its table")
    bench.add_argument(
        "target", choices=["geodesics", "contacts", "solver", "tangible"], help="what to benchmark"
    )
    bench.add_argument("--repeat", type=int, default=7, help="runs per timing (the median is shown)")
    bench.add_argument("--rays", type=int, default=2000, help="rays / targets per query")
    bench.set_defaults(run=_bench)
    ablation = commands.add_parser("ablation", help="print the contact IK ablation table (Fig. 11)")
    ablation.set_defaults(run=_ablation)
    ext = commands.add_parser("build-extension", help="build the Blender extension zips (one per platform)")
    ext.add_argument("--output", "-o", default="dist", help="folder for the zips (default: dist)")
    ext.add_argument(
        "--platform", action="append", choices=["linux-x64", "windows-x64", "macos-arm64", "macos-x64"],
        help="a platform to build for (repeatable; default: linux-x64)",
    )  # fmt: skip
    ext.add_argument("--all-platforms", action="store_true", help="build for every supported platform")
    ext.set_defaults(run=_build_extension)
    demo = commands.add_parser("demo", help="pose a procedural hand on a mug; save, render and summarize")
    demo.add_argument("--out", default="demo", help="folder for demo.blend, demo.png, contacts.json")
    demo.add_argument("--no-render", action="store_true", help="skip the Cycles render")
    demo.set_defaults(run=_demo)
    pose = commands.add_parser("pose", help="pose the hand of a saved scene from its contacts")
    pose.add_argument("scene", help="the .blend to pose (never written unless --overwrite)")
    pose.add_argument("--output", "-o", required=True, help="the posed .blend to write")
    pose.add_argument("--hand", help="the hand mesh object (default: the scene's Contact tab choice)")
    pose.add_argument("--object", help="the object mesh (default: the scene's Contact tab choice)")
    pose.add_argument("--contacts", help="a pairing file to use instead of the scene's stored contacts")
    pose.add_argument(
        "--remap", action="store_true", help="project a pairing file made for other meshes by position"
    )
    pose.add_argument("--frame", type=int, help="pose at this frame and key the pose there")
    pose.add_argument("--stage", choices=["ROOT", "ALL", "SELECTED"], default="ALL", help="which bones move")
    pose.add_argument("--overwrite", action="store_true", help="allow the output to be the input scene")
    pose.set_defaults(run=_pose)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "repeat", 1) < 1:
        build_parser().error("--repeat must be at least 1")
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
