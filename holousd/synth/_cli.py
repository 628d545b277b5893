"""Sub-commands of the synth domain: ``example``."""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["add_commands"]


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``example`` on the ``holousd`` parser."""
    example = subparsers.add_parser(
        "example",
        help="write the bundled example scene (table, book, mug, box) to a folder",
        description="Write a small, complete example scene to OUT/scene.usda with its assets: a floor and wall, "
        "a table (explicit convex decomposition), a book on it, a mug on the book and a box beside the book, "
        "with meshes, SDF grids, splats bound to faces, physics and support relations.",
    )
    example.add_argument("out", type=Path, metavar="OUT", help="folder to write scene.usda and assets/ into")
    example.add_argument("--seed", type=int, default=0, help="seed of the splat sampling")
    example.add_argument("--overwrite", action="store_true", help="replace an existing OUT/scene.usda")
    example.set_defaults(handler=_example)


def _example(args: argparse.Namespace) -> int:
    from holousd.synth._example import build_example_scene

    path = build_example_scene(args.out, seed=args.seed, overwrite=args.overwrite)
    print(f"wrote {path}")
    print(f"next: holousd info {path}")
    return 0
