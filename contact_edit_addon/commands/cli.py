"""The ``contact-edit`` command.

Subcommands:

* ``bench geodesics`` — time the geodesic core side by side with potpourri3d and pygeodesic.
* ``bench contacts`` — time the contact model (parameterize, edits, transfer, atlas).
* ``bench layouts`` — solve the layouts a person makes (pads slid by eye, the object carried away and
  turned), then edit one pad; success per bin of turn, flips and seconds (``--paper`` for Contact Edit's
  solve beside it).
* ``bench solver`` — time contact IK (analytic against finite-difference gradients, NLopt's optimizers
  side by side) and the flex-to-contact grasp.
* ``bench rigs`` — contact IK on a Rigify hand (through its controls, constraints and B-Bones) beside the
  same contacts on the procedural human hand.
* ``bench operators`` — how long each interactive operator holds Blender's main thread, on the demo's scene.
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

``demo``, ``pose``, ``bench rigs`` and ``bench operators`` need Blender's Python module
(``pip install -e ".[blender]"`` in the checkout).

No command writes over one of its input files, even with ``--overwrite``, nor replaces an existing
output file without ``--overwrite`` (:mod:`.outputs`; a retarget's folder holding its run's frames is
that run's own, which it resumes); ``build-extension`` replaces the zips of the version it builds. An
output file has its format's extension (``pose``: .blend; ``synthesize``, ``import-grab``: .npz).

Errors in the input end a command with one line on stderr, ``contact-edit <command>: <what is wrong>``,
and exit status 1 (``--debug`` adds the traceback); Ctrl-C ends it with a line saying what is kept and
exit status 130, SIGTERM with the same line and exit status 143. Progress goes to stderr: bars on a
terminal, plain periodic lines elsewhere.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator


class _InputError(Exception):
    """Bad input the command line itself finds (an output path that cannot be written, …)."""


def _count(least: int = 1, why: str = "") -> Callable[[str], int]:
    """The argparse type of every count option: a whole number of at least ``least`` (1 unless ``why``,
    in parentheses after the figure, says what needs more). An absent option keeps its default (None:
    the command's own choice); a given 0 is never taken for "the default"."""

    def count(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < least:
            raise argparse.ArgumentTypeError(
                f"must be at least {least}{f' ({why})' if why else ''}, got {value}"
            )
        return value

    count.__name__ = "count"  # what argparse calls the type in its own messages
    return count


def _output_file(path: str) -> None:
    """Refuse an output file that cannot be written before any work is done."""
    from pathlib import Path

    target = Path(path)
    if target.is_dir():
        raise _InputError(f"{path}: a folder; name the file to write")
    if not target.resolve().parent.is_dir():
        raise _InputError(f"{path}: no such folder for the output ({target.resolve().parent})")


def _output_folder(path: str) -> None:
    from pathlib import Path

    if Path(path).exists() and not Path(path).is_dir():
        raise _InputError(f"{path}: not a folder (the output is a folder of files)")


def _check_outputs(outputs, inputs, overwrite: bool, **options) -> None:
    """Refuse, before any work, outputs that are inputs, and existing ones unless ``overwrite``."""
    from .outputs import check_outputs

    check_outputs(outputs, inputs, overwrite=overwrite, error=_InputError, **options)


def _progress(what: str) -> None:
    print(f"  {what} ...", file=sys.stderr, flush=True)


def _clock(seconds: float) -> str:
    """``m:ss`` (``h:mm:ss`` from an hour on)."""
    s = max(int(seconds), 0)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class _StageBars:
    """Progress of a job's stages on a stream (stderr): ``bars(stage, done, total)``, or with a ``note``.

    On a terminal each stage gets a bar, redrawn in place (at most every ``redraw`` seconds), with the
    stage's elapsed time and the time left estimated from its rate so far. Elsewhere (a pipe, a log
    file, CI) no bar: plain lines when a stage starts, after each further tenth of it or ``every``
    seconds, and when it ends. ``capped``: the total is an upper bound (a solve's evaluation budget),
    so the time left is one too. Use it as a context manager (or call :meth:`close`) so that the last
    line is finished, also when the job fails. ``stream`` (default: ``sys.stderr`` when called),
    ``clock`` and ``tty`` (default: whether the stream is a terminal) are there for tests.
    """

    WIDTH = 30

    def __init__(self, stream=None, clock=time.monotonic, tty: bool | None = None, every: float = 5.0,
                 redraw: float = 0.1, capped: bool = False):  # fmt: skip
        self._stream, self.clock, self._tty = stream, clock, tty
        self.every, self.redraw, self.capped = every, redraw, capped
        self.stage = None

    @property
    def stream(self):
        return self._stream if self._stream is not None else sys.stderr

    @property
    def tty(self) -> bool:
        if self._tty is None:
            try:
                self._tty = bool(self.stream.isatty())
            except (AttributeError, ValueError, OSError):
                self._tty = False
        return self._tty

    def __enter__(self) -> _StageBars:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __call__(self, stage: str, done: int, total: int, note: str = "") -> None:
        now = self.clock()
        if stage != self.stage:
            self._finish()
            self.stage, self.started, self.first = stage, now, done
            self.shown, self.shown_at, self.drawn = None, now, 0
        self.done, self.total, self.note, self.now = done, total, note, now
        if self.tty:
            if self.shown is None or done >= total or now - self.shown_at >= self.redraw:
                self._draw()
        elif (
            self.shown is None
            or (done >= total and self.shown < total)
            or done - self.shown >= max(total, 1) / 10
            or (now - self.shown_at >= self.every and done != self.shown)
        ):
            self._line()

    def close(self) -> None:
        self._finish()
        self.stage = None

    def _status(self, final: bool = False) -> str:
        done, total = self.done, self.total
        elapsed = self.now - self.started
        text = f"{done}/{total}"
        if not self.capped and total > 0:
            text += f" ({100 * min(done, total) // total}%)"
        if self.note:
            text += f" {self.note}"
        text += f", {_clock(elapsed)} elapsed"
        if not final and done < total and done > self.first and elapsed > 0:
            left = (total - done) * elapsed / (done - self.first)
            text += f", {'at most ' if self.capped else ''}~{_clock(left)} left"
        return text

    def _draw(self, final: bool = False) -> None:
        filled = int(self.WIDTH * min(max(self.done, 0), self.total) / max(self.total, 1))
        bar = f"  {self.stage:<9} [{'#' * filled}{'.' * (self.WIDTH - filled)}] {self._status(final)}"
        self.stream.write(f"\r{bar}{' ' * max(self.drawn - len(bar), 0)}")
        self.stream.flush()
        self.shown, self.shown_at, self.drawn = self.done, self.now, len(bar)

    def _line(self, final: bool = False) -> None:
        print(f"  {self.stage:<9} {self._status(final)}", file=self.stream, flush=True)
        self.shown, self.shown_at = self.done, self.now

    def _finish(self) -> None:
        """End the current stage's output: the bar's last state and a newline, or a last line."""
        if self.stage is None or self.shown is None:
            return
        if self.tty:
            self.now = self.clock()
            self._draw(final=True)
            print(file=self.stream, flush=True)
        elif self.shown != self.done:
            self.now = self.clock()
            self._line(final=True)


def _bench(args: argparse.Namespace) -> int:
    from geodesics import benchmark

    runs = f"median of {args.repeat} runs after {benchmark.WARMUP} untimed ones"
    if args.target in ("rigs", "operators") and _blender() is None:
        return 2
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

        with _StageBars() as bars:
            report = retarget_benchmark.run(frames=args.frames, progress=bars)
        print(retarget_benchmark.format_report(report))
        return 0
    elif args.target == "rigs":
        from .batch import quiet_stdout

        with quiet_stdout(not args.debug):  # Rigify's Generate Rig reports every step on stdout
            rows = rig_benchmark.run(repeat=args.repeat, progress=_progress)
    elif args.target == "operators":
        from . import operator_benchmark
        from .batch import quiet_stdout

        with quiet_stdout(not args.debug):
            rows = operator_benchmark.run(repeat=args.repeat, progress=_progress)
    elif args.target == "layouts":
        from solver import layout_benchmark

        solve = "paper" if args.paper else "default"
        rows = layout_benchmark.run(per_bin=args.per_bin, progress=_progress, solve=solve)
        print(layout_benchmark.format_table(rows))
        return 0
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
    paths = build.build_extension(Path(args.output), platforms=platforms, progress=_progress)
    for path in paths:
        print(path)
    return 0


def _blender():
    """Import bpy and register the add-on's classes in it (a script's Blender, not an installed one)."""
    try:
        import bpy  # noqa: F401
    except ImportError:
        print(
            "contact-edit: this command needs Blender's Python module (bpy 5.0.1, Python 3.11); install it "
            'with pip install -e ".[blender]" in the checkout',
            file=sys.stderr,
        )
        return None
    import contact_edit_addon

    contact_edit_addon.register()
    return contact_edit_addon


def _demo(args: argparse.Namespace) -> int:
    from pathlib import Path

    _output_folder(args.out)
    if _blender() is None:
        return 2
    from . import demo

    written = [k for k in demo.FILES if k != "image" or not args.no_render]
    outputs = [Path(args.out) / demo.FILES[k] for k in written]
    _check_outputs(outputs, {}, args.overwrite, instead="choose another folder (--out)")

    result = demo.run(args.out, render=not args.no_render, progress=_progress)
    print(f"contact-edit demo: a procedural human hand grasps a mug ({result.seconds:.1f} s in all)")
    print(f"  pads painted on the hand: {len(result.painted)} ({', '.join(result.painted)})")
    print(f"  pads transferred onto the mug: {len(result.transferred)} ({result.contacts} contact points)")
    missed = [name for name in result.painted if name not in result.touching]
    touching = f"{len(result.touching)}, not {', '.join(missed)}" if missed else f"all {len(result.painted)}"
    print(f"  pads touching the mug after the solve: {touching}")
    print(f"  deepest vertex of the hand inside the mug: {1e3 * result.deepest:.2f} mm")
    print(f"  deepest point of its faces inside the mug: {1e3 * result.deepest_face:.2f} mm")
    print(f"  solve: {result.summary}")
    print(f"  scene:    {result.blend}")
    print(f"  contacts: {result.contacts_file}")
    if result.image is not None:
        print(f"  render:   {result.image}")
    return 0


def _pose(args: argparse.Namespace) -> int:
    if _blender() is None:
        return 2
    from ..bridge import BridgeError
    from . import batch

    with _StageBars(capped=True) as bars:
        try:
            summary = batch.pose_scene(
                args.scene, args.output, hand=args.hand, target=args.object, contacts=args.contacts,
                frame=args.frame, stage=args.stage, overwrite=args.overwrite, remap=args.remap,
                progress=lambda done, total, energy: bars("solving", done, total, f"energy {energy:.4g}"),
                quiet=not args.debug,
            )  # fmt: skip
        except (batch.SceneChoiceError, batch.ObjectChoiceError) as err:  # in the command line's words
            raise BridgeError(err.message("--hand NAME", "--object NAME")) from err
    print(f"contact-edit pose: {summary}")
    print(f"  saved {args.output}")
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    from solver.retarget import synthetic

    _output_file(args.output)
    _check_outputs([args.output], {}, args.overwrite, suffix=".npz")
    with _StageBars() as bars:
        motion = synthetic.generate(
            args.object, frames=args.frames, fps=args.fps, seed=args.seed, scale=args.scale,
            density=args.density, progress=bars,
        )  # fmt: skip
    motion.save(args.output)
    counts = motion.hand_contacts.count()
    print(f"contact-edit synthesize: {motion}; contacts per touching frame: median {int(_median(counts))}")
    print(f"  saved {args.output}")
    return 0


def _median(counts) -> float:
    import numpy as np

    touching = counts[counts > 0]
    return float(np.median(touching)) if touching.size else 0.0


#: The retarget's folder of per-frame results, inside its output folder.
_FRAMES = "frames"

# solver.retarget.grab.GRAB_FPS, solver.retarget.pairing.DEFAULT_CUTOFF and the fewest control points per
# DOF the spline fit takes (solver.retarget.spline.DEGREE + 1), spelled out so that building the parser
# does not import the solver (a test checks they agree).
_GRAB_FPS, _CUTOFF, _SPLINE_LEAST = 120.0, 0.01, 4


def _import_grab(args: argparse.Namespace) -> int:
    from geodesics import load_mesh
    from solver.retarget import grab, pair_motion

    _output_file(args.output)
    inputs = {
        args.motion: "the GRAB motion",
        args.hand_mesh: "the hand mesh (--hand-mesh)",
        args.object_mesh: "the object mesh (--object-mesh)",
    }
    _check_outputs([args.output], inputs, args.overwrite, instead="choose another output (-o)", suffix=".npz")
    hand_mesh = load_mesh(args.hand_mesh)
    object_mesh = load_mesh(args.object_mesh)
    motion = grab.load_grab(args.motion, hand_mesh, object_mesh, fps=args.fps, pair=False)
    pairing = None
    if not args.no_pair:
        with _StageBars() as bars:
            pairing = pair_motion(
                motion,
                "object",
                cutoff=args.cutoff,
                progress=lambda done, total: bars("pairing", done, total),
            )
        motion = pairing.apply(motion)
    motion.save(args.output)
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

    from solver.retarget import RetargetWeights

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
    from solver.retarget import HandSpec, Motion, RetargetWeights, annotate, annotations, pipeline

    out = Path(args.output)
    _output_folder(args.output)
    frames = out / _FRAMES
    # A folder holding frames is a run's own (the frames say whose: another run's are refused), and so
    # are the results in it, which a resumed or extended run writes again.
    _check_outputs(
        [out / name for name in pipeline.RESULT_FILES.values()],
        {args.motion: "the source motion", args.annotation: "the annotation (--annotation)"},
        args.overwrite or frames.is_dir(),
        folders=[frames],
        instead="choose another output folder (-o)",
    )
    motion = Motion.load(args.motion)
    target = HandSpec(args.target, args.scale)
    if args.annotation:
        annotation = annotations.HandPairAnnotation.load(args.annotation)
    elif motion.source_kind is None:
        raise SolverError(
            "the motion's source hand is not a procedural one; give its annotation with --annotation"
        )
    else:
        source = HandSpec(motion.source_kind, motion.source_scale).build()
        annotation = annotate.default_annotation(source, target.build())
    weights = RetargetWeights(**dict(args.weight or ()))
    options = pipeline.RetargetOptions(
        weights=replace(weights, c=0.0) if args.no_contacts else weights,
        root_pass=not args.no_root_pass, refine=not args.no_refine, n_control=args.control,
        baselines=args.baselines,
    )  # fmt: skip
    with _StageBars() as bars:
        result = pipeline.retarget(
            motion, target, annotation, options, folder=frames, workers=args.workers,
            scheduler=args.scheduler, progress=bars,
        )  # fmt: skip
    title = f"{Path(args.motion).name}: {motion.n_frames} frames onto {args.target} (scale {args.scale:g})"
    plot = not args.no_plot and importlib.util.find_spec("matplotlib") is not None
    paths = pipeline.save_result(result, out, annotation, plot=plot, rig=target.build().rig, title=title)
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
        print(
            "  metrics.png not written: matplotlib is not installed "
            "(pip install -e '.[plots]' in the checkout)"
        )
    sys.stdout.flush()
    for warning in summary.get("warnings", []):
        print(f"  warning: {warning}", file=sys.stderr)
    return 0


def _version() -> str:
    """The installed distribution's version (the source tree's when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("contact-edit")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without installing
        return "unknown (not installed)"


class _Help(argparse.ArgumentDefaultsHelpFormatter):
    """Help that shows every option's default. An option whose default is "not given" (None) says in its
    own help what happens then; a flag is off unless given; a required one has none."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False or action.required:
            return action.help
        return super()._get_help_string(action)


#: Makes a subcommand's parser from its name, one-line help and description (with the command's help
#: format and ``--debug``); each subcommand adds its arguments to it.
_Subcommand = Callable[[str, str, str], argparse.ArgumentParser]


def build_parser() -> argparse.ArgumentParser:
    """The command line: the options every subcommand shares, then each subcommand's own."""
    parser = argparse.ArgumentParser(
        prog="contact-edit",
        description="Pose hands against objects by their contact areas, retarget hand-object motions and "
        "drive rigs from the puppet device, from the command line.",
        formatter_class=_Help,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument(
        "--debug", action="store_true", help="on an error, show its traceback (and Blender's own output)"
    )
    # Also accepted after the command (its default is not set there, so it never overrides the above).
    debug = argparse.ArgumentParser(add_help=False)
    debug.add_argument(
        "--debug", action="store_true", default=argparse.SUPPRESS, help="as contact-edit --debug does"
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help: str, description: str) -> argparse.ArgumentParser:
        return commands.add_parser(
            name, help=help, description=description, formatter_class=_Help, parents=[debug]
        )

    for add in (
        _bench_parser,
        _ablation_parser,
        _build_extension_parser,
        _demo_parser,
        _pose_parser,
        _synthesize_parser,
        _import_grab_parser,
        _retarget_parser,
    ):
        add(command)
    return parser


_OVERWRITE_HELP = "replace an existing output file (never an input file: those are never written)"


def _bench_parser(command: _Subcommand) -> None:
    """The ``bench`` subcommand's arguments."""
    bench = command(
        "bench",
        "run a benchmark and print its table",
        "Time a part of the project and print a table of medians, beside a peer library or the "
        "procedural hand where one exists.",
    )
    bench.add_argument(
        "target",
        choices=["geodesics", "contacts", "solver", "layouts", "rigs", "operators", "tangible", "retarget"],
        help="what to benchmark",
    )
    bench.add_argument("--repeat", type=_count(), default=7, help="runs per timing (the median is shown)")
    bench.add_argument("--rays", type=_count(), default=2000, help="geodesics: rays / targets per query")
    bench.add_argument("--frames", type=_count(), default=1000, help="retarget: frames of the motion")
    bench.add_argument(
        "--per-bin", type=_count(), default=1, help="layouts: layouts per object and bin of turn"
    )
    bench.add_argument(
        "--paper",
        action="store_true",
        help="layouts: solve as Contact Edit does (SLSQP from rest), to compare",
    )
    bench.set_defaults(run=_bench)


def _ablation_parser(command: _Subcommand) -> None:
    """The ``ablation`` subcommand's arguments."""
    ablation = command(
        "ablation",
        "print the contact IK ablation table (Fig. 11)",
        "Solve the same grasps with each term of Contact Edit's Eq. 2 removed in turn and print "
        "the contact errors, as the paper's Fig. 11.",
    )
    ablation.set_defaults(run=_ablation)


def _build_extension_parser(command: _Subcommand) -> None:
    """The ``build-extension`` subcommand's arguments."""
    ext = command(
        "build-extension",
        "build the Blender extension zips (one per platform)",
        "Build the Blender extension as one zip per platform, with every run-time dependency bundled as "
        "wheels, ready for Blender's Install from Disk.",
    )
    ext.add_argument("--output", "-o", default="dist", help="folder for the zips")
    ext.add_argument(
        "--platform", action="append", choices=["linux-x64", "windows-x64", "macos-arm64", "macos-x64"],
        help="a platform to build for, repeatable (default: linux-x64)",
    )  # fmt: skip
    ext.add_argument("--all-platforms", action="store_true", help="build for every supported platform")
    ext.set_defaults(run=_build_extension)


def _demo_parser(command: _Subcommand) -> None:
    """The ``demo`` subcommand's arguments."""
    demo = command(
        "demo",
        "pose a procedural hand on a mug; save, render and summarize",
        "The embedded default job: build a procedural hand and a mug, brush a contact pad on each "
        "fingertip and the palm, wrap the fingers around the mug, transfer the pads where they land, "
        "solve the grasp from the open hand, key it, measure which pads touch, save and render.",
    )
    demo.add_argument("--out", default="demo", help="folder for demo.blend, demo.png, contacts.json")
    demo.add_argument("--no-render", action="store_true", help="skip the Cycles render")
    demo.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    demo.set_defaults(run=_demo)


def _pose_parser(command: _Subcommand) -> None:
    """The ``pose`` subcommand's arguments."""
    pose = command(
        "pose",
        "pose the hand of a saved scene from its contacts",
        "Open a saved .blend, pose its hand so that its contact patches meet the object's, and save the "
        "result to a new .blend (written whole or not at all; never over the scene or the pairing file, "
        "over another existing file only with --overwrite).",
    )
    pose.add_argument("scene", help="the .blend to pose (never written)")
    pose.add_argument("--output", "-o", required=True, help="the posed .blend to write")
    pose.add_argument("--hand", help="the hand mesh object (default: the scene's Contact tab choice)")
    pose.add_argument("--object", help="the object mesh (default: the scene's Contact tab choice)")
    pose.add_argument(
        "--contacts", help="a pairing file to use instead of the scene's contacts (default: the stored ones)"
    )
    pose.add_argument(
        "--remap", action="store_true", help="project a pairing file made for other meshes by position"
    )
    pose.add_argument(
        "--frame", type=int,
        help="pose at this frame and key the pose there (default: the scene's current frame, keyed only "
        "if the armature is animated)",
    )  # fmt: skip
    pose.add_argument("--stage", choices=["ROOT", "ALL", "SELECTED"], default="ALL", help="which bones move")
    pose.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    pose.set_defaults(run=_pose)


def _synthesize_parser(command: _Subcommand) -> None:
    """The ``synthesize`` subcommand's arguments."""
    synth = command(
        "synthesize",
        "write a synthetic hand-object manipulation (.npz motion)",
        "Write a synthetic manipulation of an object by the procedural human hand, with its contacts "
        "and ground truth, in the motion format that 'retarget' reads.",
    )
    synth.add_argument("output", help="the motion file to write (.npz)")
    synth.add_argument(
        "--object", default="mug", choices=["mug", "cylinder", "box", "sphere"],
        help="the object the hand manipulates",
    )  # fmt: skip
    synth.add_argument("--frames", type=_count(), default=600, help="frame count")
    synth.add_argument("--fps", type=float, default=120.0, help="frame rate")
    synth.add_argument("--seed", type=int, default=0, help="draws the motion's variations")
    synth.add_argument("--scale", type=float, default=1.0, help="scale of the whole scene")
    synth.add_argument("--density", type=float, default=10.0, help="hand contact samples per cm²")
    synth.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    synth.set_defaults(run=_synthesize)


def _import_grab_parser(command: _Subcommand) -> None:
    """The ``import-grab`` subcommand's arguments."""
    imp = command(
        "import-grab",
        "import a GRAB motion exported by the retargeting paper's authors (.npz)",
        "Read a GRAB motion as the retargeting paper's authors export it (the motion .npz and the hand "
        "and object meshes), pair its object contacts with the hand and save it in the motion format.",
    )
    imp.add_argument("motion", help="the authors' export (*_right_full_export_motion.npz)")
    imp.add_argument("--hand-mesh", required=True, help="the exported hand mesh (*_full_export_handmesh.obj)")
    imp.add_argument(
        "--object-mesh", required=True, help="the exported object mesh (*_full_export_objectmesh.obj)"
    )
    imp.add_argument("--output", "-o", required=True, help="the motion file to write (.npz)")
    imp.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    imp.add_argument("--fps", type=float, default=_GRAB_FPS, help="frame rate (GRAB's)")
    imp.add_argument(
        "--cutoff", type=float, default=_CUTOFF,
        help="pairing distance ε in metres: farther hand hits are dropped",
    )  # fmt: skip
    imp.add_argument(
        "--no-pair", action="store_true",
        help="keep the object contacts as they are; do not find hand contacts (default: pair them)",
    )  # fmt: skip
    imp.set_defaults(run=_import_grab)


def _retarget_parser(command: _Subcommand) -> None:
    """The ``retarget`` subcommand's arguments."""
    ret = command(
        "retarget",
        "retarget a motion onto another hand",
        "Retarget a hand-object motion onto another hand: per-frame contact solves (in parallel "
        "processes or on a Dask cluster), refinement, a spline fit, metrics and plots. The frames are "
        "kept in OUTPUT/frames as they finish, so an interrupted run resumes when run again.",
    )
    ret.add_argument("motion", help="the source motion (.npz, see 'synthesize')")
    ret.add_argument("--target", required=True, help="the target hand: human, witch, alien, tentacle")
    ret.add_argument(
        "--scale", type=float, default=1.0, help="the target hand's scale (child 0.75, large 1.25)"
    )
    ret.add_argument("--output", "-o", required=True, help="output folder (resumes if it holds this run)")
    ret.add_argument(
        "--overwrite", action="store_true",
        help="replace result files in an output folder that holds no run's frames (never an input)",
    )  # fmt: skip
    ret.add_argument(
        "--annotation", help="the hand pair's annotation, .json (default: made for procedural hands)"
    )
    ret.add_argument("--workers", type=_count(), help="worker processes (default: one per CPU)")
    ret.add_argument(
        "--scheduler", help="address of a Dask scheduler to send the frames to (default: none, solve here)"
    )
    ret.add_argument(
        "--control", type=_count(_SPLINE_LEAST, "a cubic spline's degree + 1"),
        help="spline control points per DOF (default: 10 per second)",
    )  # fmt: skip
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


# The projects' families of exceptions for bad input (module, class): a command that raises one of them
# has its message shown as it is. Looked up among the modules already imported, so that handling an
# error imports nothing (nor bpy, which the bridge needs).
_INPUT_ERRORS = (
    ("geodesics.errors", "MeshError"),
    ("geodesics.errors", "GeodesicError"),
    ("geodesics.errors", "ContactError"),
    ("solver.errors", "SolverError"),
    ("solver.retarget.motion", "MotionError"),
    ("tangible.errors", "TangibleError"),
    ("contact_edit_addon.bridge.errors", "BridgeError"),
    ("contact_edit_addon.commands.build", "BuildError"),
)


def _input_error(err: BaseException) -> bool:
    if isinstance(err, (OSError, _InputError)):
        return True
    for module, name in _INPUT_ERRORS:
        family = getattr(sys.modules.get(module), name, None)
        if isinstance(family, type) and isinstance(err, family):
            return True
    return False


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in text.splitlines() if line.strip())


def _message(err: BaseException) -> str:
    """An exception as one line: an OSError as ``file: reason``, anything else as its message."""
    if isinstance(err, OSError) and err.filename is not None and err.strerror:
        where = f"{err.filename} -> {err.filename2}" if err.filename2 is not None else f"{err.filename}"
        return _one_line(f"{where}: {err.strerror}")
    return _one_line(str(err))


def _command(args: argparse.Namespace) -> str:
    return f"{args.command} {args.target}" if args.command == "bench" else args.command


def _interrupted(args: argparse.Namespace) -> str:
    """What Ctrl-C leaves behind, and how to go on from there."""
    if args.command == "retarget":
        from pathlib import Path

        frames = Path(args.output) / _FRAMES
        return f"interrupted; run the same command again to resume (solved frames are kept in {frames})"
    if args.command == "bench" and args.target == "retarget":
        return "interrupted; the benchmark works in temporary folders, so nothing is kept (run it again anew)"
    return "interrupted"


class _Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a service manager, a job scheduler's time limit), raised where the command is so
    that it ends as Ctrl-C does: worker processes stopped and joined, what is solved kept, one line."""


def _terminate(signum, frame) -> None:
    raise _Terminated


@contextlib.contextmanager
def _sigterm_as_ctrl_c() -> Iterator[None]:
    """While the block runs (in the main thread: only it can set handlers), SIGTERM raises
    :class:`_Terminated`, a KeyboardInterrupt. Killed by the default action instead, the process would
    run no cleanup: its worker processes' queues and semaphores would be left to the resource tracker,
    which prints "leaked semaphore objects", and nothing would say what is kept."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    name = _command(args)
    try:
        with _sigterm_as_ctrl_c():
            return args.run(args)
    except KeyboardInterrupt as err:
        if args.debug:
            import traceback

            traceback.print_exc()
        print(f"contact-edit {name}: {_interrupted(args)}", file=sys.stderr, flush=True)
        return 128 + signal.SIGTERM if isinstance(err, _Terminated) else 130
    except Exception as err:
        if args.debug:
            import traceback

            traceback.print_exc()
        if _input_error(err):
            print(f"contact-edit {name}: {_message(err)}", file=sys.stderr, flush=True)
        else:
            print(
                f"contact-edit {name}: {type(err).__name__}: {_message(err) or 'no message'} (an unexpected "
                "error; run again with contact-edit --debug to see its traceback)",
                file=sys.stderr, flush=True,
            )  # fmt: skip
        return 1


if __name__ == "__main__":
    sys.exit(main())
