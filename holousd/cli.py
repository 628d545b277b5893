"""The ``holousd`` command: one entry point, one sub-command per job.

Sub-commands are contributed by the domains: each has a private ``_cli`` module with
``add_commands(subparsers)`` that registers parsers whose ``handler`` default takes the parsed namespace and
returns an exit code. This module only parses and dispatches; heavy imports happen inside the handlers.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from holousd._argtypes import HelpFormatter

__all__ = ["build_parser", "main"]

_COMMAND_MODULES = (
    "holousd.usd._cli",
    "holousd.synth._cli",
    "holousd.render._cli",
    "holousd.physics._cli",
    "holousd.stages._cli",
    "holousd.stages._pipeline_cli",
)
"""Modules that contribute sub-commands, in the order ``--help`` lists them."""
_NO_WARP_COMMANDS = frozenset({"info", "validate", "export", "example"})
"""Sub-commands that never run Warp (they skip importing it)."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose sub-command parsers show defaults in ``--help`` unless told otherwise."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    """Build the ``holousd`` argument parser with every available sub-command."""
    from holousd import __version__

    parser = argparse.ArgumentParser(
        prog="holousd",
        description=(
            "holousd turns a video of a static indoor scene into a simulation-ready, interactive USD scene graph: "
            "watertight meshes, Gaussian-splat appearance, rigid-body physics and support relations per object."
        ),
        epilog="Run 'holousd COMMAND --help' for the options of a command.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"holousd {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands", parser_class=_Parser)
    for module_name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name is None or not module_name.startswith(exc.name):
                raise
            continue  # domain not present in this build
        module.add_commands(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``holousd`` command and return its exit code (0 success, 1 failure found, 2 usage/input error)."""
    from holousd._errors import HolousdError
    from holousd._warp import quiet_warp

    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "handler", None) is None:
        parser.print_help()
        return 2
    if args.command not in _NO_WARP_COMMANDS:
        quiet_warp()  # its banner and module-load lines would land in the command's (JSON) output
    try:
        return int(args.handler(args))
    except HolousdError as exc:
        print(f"holousd {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"holousd {args.command}: interrupted; files already on disk were left as they were", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
