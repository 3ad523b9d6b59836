"""The ``contact-edit`` command.

Subcommands:

* ``bench geodesics`` — time the geodesic core side by side with potpourri3d and pygeodesic.
"""

from __future__ import annotations

import argparse
import sys


def _bench(args: argparse.Namespace) -> int:
    from geodesics import benchmark

    print(
        f"contact-edit bench geodesics: median of {args.repeat} runs after {benchmark.WARMUP} untimed ones",
        flush=True,
    )
    rows = benchmark.run(
        repeat=args.repeat,
        rays=args.rays,
        progress=lambda what: print(f"  running {what} ...", file=sys.stderr, flush=True),
    )
    print(benchmark.format_table(rows))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="contact-edit", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    bench = commands.add_parser("bench", help="run a benchmark and print its table")
    bench.add_argument("target", choices=["geodesics"], help="what to benchmark")
    bench.add_argument("--repeat", type=int, default=7, help="runs per timing (the median is shown)")
    bench.add_argument("--rays", type=int, default=2000, help="rays / targets per query")
    bench.set_defaults(run=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "repeat", 1) < 1:
        build_parser().error("--repeat must be at least 1")
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
