"""``arroyo`` command line: parse arguments, call one library function, map errors to exit
codes (0 ok, 1 frames failed or ``status --verify`` found damage, 2 bad catalog/params/run
directory, 3 run locked, 4 store error, 130 interrupted, 141 output pipe closed)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence

from .errors import (
    ArroyoError,
    RunLockedError,
    StoreError,
)

__all__ = ["main", "build_parser"]

EXIT_OK, EXIT_FAILED_FRAMES, EXIT_USAGE, EXIT_LOCKED, EXIT_STORE = 0, 1, 2, 3, 4
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a command killed by it


def _cmd_run(args: argparse.Namespace) -> int:
    from .plan import RunPlan, format_plan
    from .progress import make_progress
    from .runner import run

    callback, close = make_progress(enabled=not args.quiet and not args.dry_run)
    try:
        result = run(
            args.catalog,
            args.out,
            overrides=args.set,
            workers=args.workers,
            scheduler=args.scheduler,
            frames=args.frames,
            dry_run=args.dry_run,
            progress=callback,
            products=args.products,
            worker_wait=args.wait_for_workers,
            stage_package=args.stage_package,
        )
    finally:
        close()
    if isinstance(result, RunPlan):
        print(format_plan(result), end="")
        return EXIT_OK
    print(
        f"arroyo: run {result.run_id} -> {result.rundir}: {result.done} done, "
        f"{result.failed} failed, {result.pending} pending ({result.seconds:.1f} s)"
    )
    for frame_id, error in sorted(result.failures.items()):
        print(f"  failed {frame_id}: {error}")
    if result.notes is not None:
        from .notes import format_notes

        print(format_notes(result.notes, result.rundir), end="")
    from .plan import format_duplicates

    print(format_duplicates(result.duplicates), end="")
    return result.exit_code


def _cmd_status(args: argparse.Namespace) -> int:
    from .status import format_status, status

    report = status(args.rundir, verify=args.verify)
    print(format_status(report), end="")
    # a script checking an archive must see damage without parsing the text
    return EXIT_FAILED_FRAMES if report.damaged else EXIT_OK


def _cmd_graph(args: argparse.Namespace) -> int:
    from .graph import describe_graph

    print(describe_graph(fmt=args.format, stage_package=args.stage_package), end="")
    return EXIT_OK


def _cmd_synth(args: argparse.Namespace) -> int:
    from .synth import synthesize_archive

    path = synthesize_archive(
        args.archetype,
        args.out,
        frames=args.frames,
        seed=args.seed,
        variant=args.variant,
        size=args.size,
    )
    print(f"arroyo: wrote {args.frames} {args.archetype} frames to {path}")
    return EXIT_OK


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluate import evaluate_run, format_evaluation

    print(format_evaluation(evaluate_run(args.rundir)), end="")
    return EXIT_OK


def _cmd_query(args: argparse.Namespace) -> int:
    from .query import query_command

    return query_command(
        args.rundirs,
        args.sql,
        fmt=args.format,
        output=args.output,
        allow_running=args.allow_running,
    )


def _cmd_report(args: argparse.Namespace) -> int:
    from .report import build_report

    path = build_report(
        args.rundir, args.output, max_frames=args.max_frames, allow_running=args.allow_running
    )
    print(f"arroyo: wrote {path}")
    return EXIT_OK


def _add_stage_package(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--stage-package",
        metavar="PACKAGE",
        help="importable package whose modules declare STAGE = Stage(...) (default: "
        "$ARROYO_STAGE_PACKAGE, else the shipped 'stages')",
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``arroyo`` argument parser; each subcommand sets ``func`` to its handler."""
    parser = argparse.ArgumentParser(
        prog="arroyo",
        description="Stereo pairs of rock fields to depth maps, rock masks, descriptors and "
        "a scene graph.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="run (or resume) every stage on every frame of a catalog")
    p.add_argument("catalog", help="survey catalog (TOML)")
    p.add_argument("--out", help="run directory (default runs/<archive>)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="STAGE.PARAM=VALUE",
        help="override a stage parameter (repeatable)",
    )
    p.add_argument("--workers", type=int, help="local workers (default: all cores)")
    p.add_argument(
        "--scheduler",
        help="'threads', 'synchronous', or a dask.distributed "
        "scheduler address such as tcp://host:8786",
    )
    p.add_argument(
        "--wait-for-workers",
        type=float,
        metavar="SECONDS",
        help="with --scheduler ADDRESS: how long to wait for the first worker before stopping "
        "(default 60; raise it when workers come from a batch queue)",
    )
    p.add_argument(
        "--products",
        metavar="DIR_OR_URL",
        help="write array products and quicklooks here instead of the run directory: a "
        "shared directory or an fsspec URL such as s3://bucket/prefix (recorded; a resumed "
        "run finds it)",
    )
    p.add_argument("--frames", metavar="PATTERN", help="only frames whose id matches (glob)")
    p.add_argument("--dry-run", action="store_true", help="print what would run and why")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    _add_stage_package(p)
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("status", help="frames done / failed / pending per stage")
    p.add_argument("rundir")
    p.add_argument(
        "--verify",
        action="store_true",
        help="check recorded checksums (exit 1 if any is damaged); damaged results are "
        "redone by the next run",
    )
    p.set_defaults(func=_cmd_status)

    p = sub.add_parser("graph", help="the stage graph in order with each stage's params")
    p.add_argument("--format", choices=("text", "dot"), default="text")
    _add_stage_package(p)
    p.set_defaults(func=_cmd_graph)

    p = sub.add_parser("synth", help="render a built-in synthetic archive with ground truth")
    p.add_argument("archetype", choices=("lab", "mojave", "dunes", "lava"))
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--variant", help="archetype variant (mojave: 'viking', 0.8 m baseline)")
    p.add_argument("--size", type=int, default=500, help="frame side in pixels")
    p.add_argument("--out", required=True)
    p.set_defaults(func=_cmd_synth)

    p = sub.add_parser("evaluate", help="score a run's products against ground truth")
    p.add_argument("rundir")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser("query", help="SQL (DuckDB) over the Parquet products of runs")
    p.add_argument("rundirs", nargs="+", metavar="RUNDIR")
    p.add_argument("sql")
    p.add_argument(
        "--format",
        choices=("table", "csv", "parquet", "json"),
        help="default: from --output's suffix (.csv, .json, .parquet), else table",
    )
    p.add_argument(
        "--output", "-o", help="file to write, outside the run directories (default or -: stdout)"
    )
    p.add_argument(
        "--allow-running",
        action="store_true",
        help="query a run still in progress (sees its completed frames only)",
    )
    p.set_defaults(func=_cmd_query)

    p = sub.add_parser("report", help="write a self-contained report.html for a run")
    p.add_argument("rundir")
    p.add_argument("--output", "-o", help="where to write (default RUNDIR/report.html)")
    p.add_argument(
        "--max-frames",
        type=int,
        default=50,
        metavar="N",
        help="frames shown with images, in catalog order (default 50; 0: none)",
    )
    p.add_argument(
        "--allow-running",
        action="store_true",
        help="report on a run still in progress (its completed frames only)",
    )
    p.set_defaults(func=_cmd_report)
    return parser


def _exit_code(exc: BaseException) -> int:
    """3 for a locked run directory, 4 for a store that cannot be written, else 2 (a bad
    catalog, parameter, graph or run directory: nothing was done)."""
    if isinstance(exc, RunLockedError):
        return EXIT_LOCKED
    if isinstance(exc, StoreError):
        return EXIT_STORE
    return EXIT_USAGE


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``arroyo`` command line on ``argv`` (default ``sys.argv[1:]``); return the
    exit code (see the module docstring)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except ArroyoError as exc:
        print(f"arroyo: error: {exc}", file=sys.stderr)
        return _exit_code(exc)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"arroyo: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        # the reader went away (`arroyo query ... | head`): stop quietly, and point stdout at
        # /dev/null so that Python's flush at exit does not print a second traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        print("arroyo: interrupted; finished frames are kept, rerun to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
