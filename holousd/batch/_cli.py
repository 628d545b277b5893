"""Sub-command ``batch``: reconstruct many captures on this machine's cores or on a Ray cluster."""

from __future__ import annotations

import argparse
from pathlib import Path

from holousd._argtypes import emit_json, positive_int

__all__ = ["add_commands"]

_EPILOG = """where the work runs:
  (no --ray)        a local process pool, --workers processes (default: one per core); Ray is not imported
  --ray local       a Ray instance started on this machine for this batch
  --ray auto        the Ray cluster already running on this machine's network (`ray start --head`)
  --ray HOST:PORT   that cluster's head node
On a cluster every node must see the captures and OUT at the same paths (a shared filesystem); otherwise give
each node's captures to its own batch and gather the OUT folders afterwards. A rerun with the same OUT skips
the stages of each capture that are up to date (a batch interrupted is resumed by running it again); a capture
that fails is reported with its one-line error while the others finish. OUT/batch.json holds one row per capture."""


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``batch`` on the ``holousd`` parser."""
    batch = subparsers.add_parser(
        "batch",
        help="reconstruct many captures, one task per capture, locally or on a Ray cluster",
        description="Reconstruct every CAPTURE into OUT/<capture name>/ (the pipeline of `holousd reconstruct`, "
        "resuming), one task per capture, then print a table and write OUT/batch.json.",
        epilog=_EPILOG,
    )
    batch.add_argument("captures", nargs="+", type=Path, metavar="CAPTURE", help="capture folders (or video files)")
    batch.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder, one sub-folder each")
    batch.add_argument("--preset", choices=("fast", "default", "best"), default="default",
                       help="speed / accuracy of every capture")  # fmt: skip
    batch.add_argument("--seed", type=int, default=0, help="seed of every stage")
    batch.add_argument("--search", choices=("tree", "ground", "none"), default="tree",
                       help="s2 search mode (default: tree, the full search)")  # fmt: skip
    batch.add_argument("--until", choices=("observe", "fit", "search", "physics", "appearance"), default=None,
                       help="last stage to run (default: all)")  # fmt: skip
    batch.add_argument("--workers", type=positive_int, default=None,
                       help="local worker processes (default: one per core; ignored with --ray)")  # fmt: skip
    batch.add_argument("--ray", default=None, metavar="ADDRESS",
                       help="run on Ray: 'local', 'auto' or HOST:PORT (see below; needs holousd[ray])")  # fmt: skip
    batch.add_argument("--cpus-per-task", type=float, default=1.0, metavar="N",
                       help="cores each capture's Ray task declares (its torch threads)")  # fmt: skip
    batch.add_argument("--memory-per-task", type=float, default=3000.0, metavar="MIB",
                       help="memory each capture's Ray task declares, MiB")  # fmt: skip
    batch.add_argument("--json", action="store_true", help="print the rows as JSON instead of a table")
    batch.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    batch.set_defaults(handler=_batch)


def _batch(args: argparse.Namespace) -> int:
    from holousd._tasks import require_ray
    from holousd.batch._batch import BatchConfig, batch_table, run_batch
    from holousd.stages._pipeline import preset

    if args.ray is not None:
        require_ray()
    config = BatchConfig(pipeline=preset(args.preset, seed=args.seed, progress=False, search=args.search),
                         until=args.until,
                         workers=args.workers, ray=args.ray, num_cpus=args.cpus_per_task,
                         memory_mb=args.memory_per_task, progress=not args.no_progress)  # fmt: skip
    result = run_batch(args.captures, args.out, config)
    if args.json:
        emit_json(args, {"wall_s": result.wall_s, "captures": result.rows})
    else:
        print(batch_table(result.rows), end="")
        print(f"{len(result.rows) - len(result.failed)} of {len(result.rows)} captures done in "
              f"{result.wall_s:.1f} s; wrote {result.file}")  # fmt: skip
    return 1 if result.failed else 0
