"""The ``contact-edit`` command.

Subcommands:

* ``bench geodesics`` — time the geodesic core side by side with potpourri3d and pygeodesic.
* ``bench contacts`` — time the contact model (parameterize, edits, transfer, atlas).
* ``bench solver`` — time contact IK (analytic against finite-difference gradients, NLopt's optimizers
  side by side) and the flex-to-contact grasp.
* ``bench rigs`` — contact IK on a Rigify hand (through its controls, constraints and B-Bones) beside the
  same contacts on the procedural human hand.
* ``bench tangible`` — the puppet device's serial link under corruption, pose interpolation per frame,
  and the rig reduction's error against kit size (the paper's Fig. 7).
* ``ablation`` — the contact IK ablation of Contact Edit's Fig. 11 as a table (each term of Eq. 2 removed).
* ``build-extension`` — build the Blender extension zips, with every run-time dependency as wheels.
* ``demo`` — the embedded default job: a procedural hand grasps a mug; saves, renders, summarizes.
* ``pose`` — pose the hand of a saved scene from its contacts and save it to a new file.
* ``synthesize`` — write a synthetic hand-object manipulation with ground truth (the motion format).
* ``import-grab`` — read a GRAB motion exported by the retargeting paper's authors (``.npz`` and the hand
  and object meshes), pair its object contacts with the hand, and save it in the motion format.
* ``retarget`` — retarget a motion onto another hand: per-frame solves in parallel processes (or on a
  Dask cluster), refinement, spline fit, metrics and plots, with ``--baselines`` the §4.6 baselines and
  Table 1; an interrupted run resumes.
* ``bench retarget`` — the whole retarget of a long, densely touching motion, stage by stage, and its
  speed-up from one to two worker processes.

``demo``, ``pose`` and ``bench rigs`` need Blender's Python module (``pip install "contact-edit[blender]"``).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys


def _progress(what: str) -> None:
    print(f"  {what} ...", file=sys.stderr, flush=True)


class _StageBars:
    """A progress bar per stage on stderr: ``bars(stage, done, total)``."""

    def __init__(self):
        self.stage = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage != self.stage:
            if self.stage is not None:
                print(file=sys.stderr)
            self.stage = stage
        filled = int(30 * min(done, total) / max(total, 1))
        print(f"\r  {stage:<9} [{'#' * filled}{'.' * (30 - filled)}] {done}/{total}",
              end="", file=sys.stderr, flush=True)  # fmt: skip

    def close(self) -> None:
        if self.stage is not None:
            print(file=sys.stderr)


def _bench(args: argparse.Namespace) -> int:
    from geodesics import benchmark

    runs = f"median of {args.repeat} runs after {benchmark.WARMUP} untimed ones"
    if args.target == "rigs":
        from . import rig_benchmark

        runs = f"evaluations: median of {rig_benchmark.EVALUATIONS}; solves: median of {args.repeat} poses"
    if args.target != "retarget":  # one long run, timed stage by stage
        print(f"contact-edit bench {args.target}: {runs}", flush=True)
    if args.target == "geodesics":
        rows = benchmark.run(repeat=args.repeat, rays=args.rays, progress=_progress)
    elif args.target == "solver":
        from solver import benchmark as solver_benchmark

        print(f"  finite-difference solves: median of min(repeat, {solver_benchmark.FD_RUNS}), no warm-up")
        rows = solver_benchmark.run(repeat=args.repeat, progress=_progress)
    elif args.target == "retarget":
        from solver.retarget import benchmark as retarget_benchmark

        print(
            retarget_benchmark.format_report(
                retarget_benchmark.run(frames=args.frames, progress=_StageBars())
            )
        )
        return 0
    elif args.target == "rigs":
        rows = rig_benchmark.run(repeat=args.repeat, progress=_progress)
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


def _synthesize(args: argparse.Namespace) -> int:
    from solver import SolverError
    from solver.retarget import synthetic

    bars = _StageBars()
    try:
        motion = synthetic.generate(
            args.object, frames=args.frames, fps=args.fps, seed=args.seed, scale=args.scale,
            density=args.density, progress=bars,
        )  # fmt: skip
        bars.close()
        motion.save(args.output)
    except (SolverError, OSError) as err:
        bars.close()
        print(f"contact-edit synthesize: {err}", file=sys.stderr)
        return 1
    counts = motion.hand_contacts.count()
    print(f"contact-edit synthesize: {motion}; contacts per touching frame: median {int(_median(counts))}")
    print(f"  saved {args.output}")
    return 0


def _median(counts) -> float:
    import numpy as np

    touching = counts[counts > 0]
    return float(np.median(touching)) if touching.size else 0.0


# solver.retarget.grab.GRAB_FPS and solver.retarget.pairing.DEFAULT_CUTOFF, spelled out so that building
# the parser does not import the solver (a test checks they agree).
_GRAB_FPS, _CUTOFF = 120.0, 0.01


def _import_grab(args: argparse.Namespace) -> int:
    from geodesics import MeshError
    from geodesics.meshio import load_mesh
    from solver import SolverError
    from solver.retarget import grab, pair_motion
    from solver.retarget.motion import MotionError

    bars = _StageBars()
    try:
        hand_mesh = load_mesh(args.hand_mesh)
        object_mesh = load_mesh(args.object_mesh)
        motion = grab.load_grab(args.motion, hand_mesh, object_mesh, fps=args.fps, pair=False)
        pairing = None
        if not args.no_pair:
            pairing = pair_motion(
                motion,
                "object",
                cutoff=args.cutoff,
                progress=lambda done, total: bars("pairing", done, total),
            )
            motion = pairing.apply(motion)
        bars.close()
        motion.save(args.output)
    except (MeshError, MotionError, SolverError, OSError) as err:
        bars.close()
        print(f"contact-edit import-grab: {err}", file=sys.stderr)
        return 1
    counts = motion.object_contacts.count()
    paired = ""
    if pairing is not None:
        paired = "; object contacts " + ", ".join(f"{n} {name}" for name, n in pairing.counts().items())
    print(
        f"contact-edit import-grab: {motion}; contacts per touching frame: median {int(_median(counts))}"
        f"{paired}"
    )
    print(f"  saved {args.output}")
    return 0


def _weight(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` of one Eq. 3 weight (``--weight``), checked by argparse."""
    from dataclasses import fields

    from solver.retarget.frames import RetargetWeights

    names = [f.name for f in fields(RetargetWeights)]
    name, _, value = text.partition("=")
    if name not in names:
        raise argparse.ArgumentTypeError(f"{text!r}: the weights are {', '.join(names)} (e.g. c=2)")
    try:
        number = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: {value!r} is not a number") from None
    if not (number >= 0 and number < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r}: a weight must be a finite number >= 0")
    return name, number


def _retarget(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from solver import SolverError
    from solver.retarget import annotations, pipeline, synthetic
    from solver.retarget.frames import HandSpec, RetargetWeights
    from solver.retarget.motion import Motion, MotionError

    out = Path(args.output)
    bars = _StageBars()
    try:
        motion = Motion.load(args.motion)
        target = HandSpec(args.target, args.scale)
        if args.annotation:
            annotation = annotations.HandPairAnnotation.load(args.annotation)
        elif motion.source_kind is None:
            raise SolverError(
                "the motion's source hand is not a procedural one; give its annotation with --annotation"
            )
        else:
            source = synthetic.source_hand(motion.source_kind, motion.source_scale)
            annotation = annotations.default_annotation(source, target.build())
        weights = RetargetWeights(**dict(args.weight or ()))
        options = pipeline.RetargetOptions(
            weights=replace(weights, c=0.0) if args.no_contacts else weights,
            root_pass=not args.no_root_pass, refine=not args.no_refine, n_control=args.control,
            baselines=args.baselines,
        )  # fmt: skip
        result = pipeline.retarget(
            motion, target, annotation, options, folder=out / "frames", workers=args.workers,
            scheduler=args.scheduler, progress=bars,
        )  # fmt: skip
        bars.close()
        plot = not args.no_plot and importlib.util.find_spec("matplotlib") is not None
        paths = pipeline.save_result(result, out, annotation, plot=plot, rig=target.build().rig)
    except (SolverError, MotionError, OSError) as err:
        bars.close()
        print(f"contact-edit retarget: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        bars.close()
        print(f"contact-edit retarget: interrupted; run the same command again to resume ({out / 'frames'})",
              file=sys.stderr)  # fmt: skip
        return 130
    summary = result.summary()
    length = target.build().length
    print(f"contact-edit retarget: {motion.n_frames} frames onto {args.target} (scale {args.scale})")
    for key in ("median_contact_distance_mm", "median_marker_distance_mm"):
        value = summary[key]
        shown = "n/a" if value is None else f"{value:.2f} mm ({100 * value / 1e3 / length:.2f}% of the hand)"
        print(f"  {key.replace('_mm', '').replace('_', ' ')}: {shown}")
    total = sum(result.seconds.values())
    shares = ", ".join(f"{k} {v:.1f} s ({100 * v / total:.0f}%)" for k, v in result.seconds.items())
    print(f"  time {total:.1f} s: {shares}")
    if result.table is not None:
        print("  " + result.table.text().replace("\n", "\n  "))
    for name, path in paths.items():
        print(f"  {name:<10} {path}")
    if not plot and not args.no_plot:
        print("  metrics.png not written: matplotlib is not installed (pip install 'contact-edit[plots]')")
    return 0


def _version() -> str:
    """The installed distribution's version (the source tree's when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("contact-edit")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without installing
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="contact-edit",
        description="Pose hands against objects by their contact areas, retarget hand-object motions and "
        "drive rigs from the puppet device, from the command line.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    bench = commands.add_parser("bench", help="run a benchmark and print its table")
    bench.add_argument(
        "target",
        choices=["geodesics", "contacts", "solver", "rigs", "tangible", "retarget"],
        help="what to benchmark",
    )
    bench.add_argument("--repeat", type=int, default=7, help="runs per timing (the median is shown)")
    bench.add_argument("--rays", type=int, default=2000, help="rays / targets per query")
    bench.add_argument("--frames", type=int, default=1000, help="retarget: frames of the motion")
    bench.set_defaults(run=_bench)
    ablation = commands.add_parser(
        "ablation",
        help="print the contact IK ablation table (Fig. 11)",
        description="Solve the same grasps with each term of Contact Edit's Eq. 2 removed in turn and print "
        "the contact errors, as the paper's Fig. 11.",
    )
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
    synth = commands.add_parser("synthesize", help="write a synthetic hand-object manipulation (.npz motion)")
    synth.add_argument("output", help="the motion file to write (.npz)")
    synth.add_argument(
        "--object", default="mug", choices=["mug", "cylinder", "box", "sphere"],
        help="the object the hand manipulates (default mug)",
    )  # fmt: skip
    synth.add_argument("--frames", type=int, default=600, help="frame count (default 600)")
    synth.add_argument("--fps", type=float, default=120.0, help="frame rate (default 120)")
    synth.add_argument("--seed", type=int, default=0, help="draws the motion's variations")
    synth.add_argument("--scale", type=float, default=1.0, help="scale of the whole scene")
    synth.add_argument(
        "--density", type=float, default=10.0, help="hand contact samples per cm² (default 10)"
    )
    synth.set_defaults(run=_synthesize)
    imp = commands.add_parser(
        "import-grab", help="import a GRAB motion exported by the retargeting paper's authors (.npz)"
    )
    imp.add_argument("motion", help="the authors' export (*_right_full_export_motion.npz)")
    imp.add_argument("--hand-mesh", required=True, help="the exported hand mesh (*_full_export_handmesh.obj)")
    imp.add_argument(
        "--object-mesh", required=True, help="the exported object mesh (*_full_export_objectmesh.obj)"
    )
    imp.add_argument("--output", "-o", required=True, help="the motion file to write (.npz)")
    imp.add_argument(
        "--fps", type=float, default=_GRAB_FPS, help=f"frame rate (default {_GRAB_FPS:g}, GRAB's)"
    )
    imp.add_argument(
        "--cutoff", type=float, default=_CUTOFF,
        help=f"pairing distance ε in metres: farther hand hits are dropped (default {_CUTOFF:g})",
    )  # fmt: skip
    imp.add_argument(
        "--no-pair", action="store_true",
        help="keep the object contacts as they are; do not find hand contacts (default: pair them)",
    )  # fmt: skip
    imp.set_defaults(run=_import_grab)
    ret = commands.add_parser("retarget", help="retarget a motion onto another hand")
    ret.add_argument("motion", help="the source motion (.npz, see 'synthesize')")
    ret.add_argument("--target", required=True, help="the target hand: human, witch, alien, tentacle")
    ret.add_argument(
        "--scale", type=float, default=1.0, help="the target hand's scale (child 0.75, large 1.25)"
    )
    ret.add_argument("--output", "-o", required=True, help="output folder (resumes if it holds this run)")
    ret.add_argument(
        "--annotation", help="the hand pair's annotation (.json; default: made for procedural hands)"
    )
    ret.add_argument("--workers", type=int, help="worker processes (default: one per CPU)")
    ret.add_argument("--scheduler", help="address of a Dask scheduler to send the frames to")
    ret.add_argument("--control", type=int, help="spline control points per DOF (default: 10 per second)")
    ret.add_argument(
        "--weight", action="append", type=_weight, metavar="NAME=VALUE",
        help="an Eq. 3 weight: m (markers), c (contacts), cd, cn, t (table), j (prior); repeatable "
        "(default: the paper's, m=1 c=1 cd=1 cn=1 t=1, and j=10)",
    )  # fmt: skip
    ret.add_argument("--no-contacts", action="store_true", help="ablation: markers only (λc = 0)")
    ret.add_argument("--no-root-pass", action="store_true", help="ablation: no root pre-solve")
    ret.add_argument("--no-refine", action="store_true", help="skip the refinement")
    ret.add_argument("--no-plot", action="store_true", help="do not write metrics.png")
    ret.add_argument(
        "--baselines", action="store_true",
        help="also run the §4.6 baselines (fingertip keypoints, DexPilot keyvectors) and write Table 1",
    )  # fmt: skip
    ret.set_defaults(run=_retarget)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "repeat", 1) < 1:
        build_parser().error("--repeat must be at least 1")
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
