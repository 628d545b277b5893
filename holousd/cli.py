"""The ``holousd`` command: one entry point, one sub-command per job.

Sub-commands are contributed by the domains: each has a private ``_cli`` module with
``add_commands(subparsers)`` that registers parsers whose ``handler`` default takes the parsed namespace and
returns an exit code. This module only parses and dispatches; heavy imports happen inside the handlers.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import importlib
import io
import os
import signal
import sys
from collections.abc import Iterator, Sequence

from holousd._argtypes import HelpFormatter

__all__ = ["build_parser", "main"]

_COMMAND_MODULES = (
    "holousd.usd._cli",
    "holousd.synth._cli",
    "holousd.render._cli",
    "holousd.physics._cli",
    "holousd.stages._cli",
    "holousd.stages._pipeline_cli",
    "holousd.batch._cli",
    "holousd.view._cli",
)
"""Modules that contribute sub-commands, in the order ``--help`` lists them."""
_NO_WARP_COMMANDS = frozenset({"info", "validate", "export", "example"})
"""Sub-commands that never run Warp (they skip importing it)."""


EXIT_INTERNAL = 70
"""Exit code of a failure that is holousd's fault, not the input's (a bug: re-run with --verbose and report it)."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose sub-command parsers show defaults in ``--help`` unless told otherwise, and whose
    usage errors are one line (the mistake and where to read more), not the whole usage block."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}; see '{self.prog} --help'\n")


def build_parser() -> argparse.ArgumentParser:
    """Build the ``holousd`` argument parser with every available sub-command."""
    from holousd import __version__

    parser = _Parser(
        prog="holousd",
        description=(
            "holousd turns a video of a static indoor scene into a simulation-ready, interactive USD scene graph: "
            "watertight meshes, Gaussian-splat appearance, rigid-body physics and support relations per object."
        ),
        epilog="Run 'holousd COMMAND --help' for the options of a command.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"holousd {__version__}")
    parser.add_argument("--verbose", action="store_true", help=_VERBOSE_HELP)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands", parser_class=_Parser)
    for module_name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name is None or not module_name.startswith(exc.name):
                raise
            continue  # domain not present in this build
        module.add_commands(subparsers)
    for sub in subparsers.choices.values():  # also after the command: holousd reconstruct ... --verbose
        sub.add_argument("--verbose", action="store_true", default=argparse.SUPPRESS, help=_VERBOSE_HELP)
    return parser


_VERBOSE_HELP = "on an error, also print the Python traceback (for bug reports)"


@contextlib.contextmanager
def _json_stdout() -> Iterator[io.TextIOBase]:
    """Keep everything but the command's JSON off stdout while a ``--json`` command runs.

    Native libraries (the convex decomposition, simulators) and Python libraries print progress to stdout; here
    both the process's file descriptor 1 and ``sys.stdout`` point at stderr, and the command prints its JSON to
    the stream this yields, the real stdout.
    """
    sys.stdout.flush()
    try:
        real_fd = sys.stdout.fileno() == 1
    except (AttributeError, OSError, io.UnsupportedOperation):
        real_fd = False  # stdout is captured (tests): only the descriptor needs redirecting
    saved = os.dup(1)
    original = sys.stdout
    out: io.TextIOBase = open(os.dup(saved), "w", encoding="utf-8") if real_fd else original  # noqa: SIM115
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    try:
        yield out
    finally:
        with contextlib.suppress(Exception):
            ctypes.CDLL(None).fflush(None)  # C stdio buffers written before fd 1 is restored
        with contextlib.suppress(Exception):
            original.flush()  # what a library wrote through a reference it kept to sys.stdout: to stderr too
        sys.stdout = original
        os.dup2(saved, 1)
        os.close(saved)
        try:
            out.flush()
        finally:
            if out is not original:
                with contextlib.suppress(Exception):
                    out.close()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``holousd`` command and return its exit code: 0 success, 1 a check found problems, 2 bad input or
    usage (one line naming the file or option and the fix), 70 an internal error, 130 interrupted."""
    from holousd._errors import HolousdError
    from holousd._paths import describe_os_error
    from holousd._warp import quiet_warp

    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "handler", None) is None:
        parser.print_help()
        return 2
    if args.command not in _NO_WARP_COMMANDS:
        quiet_warp()  # its banner and module-load lines would land in the command's (JSON) output
    verbose = bool(getattr(args, "verbose", False))
    signal.signal(signal.SIGTERM, _terminate)  # kill: the same clean stop as Ctrl-C (transactions roll back)
    prefix = f"holousd {args.command}"
    try:
        _check_outputs(args)
        if getattr(args, "json", False):
            with _json_stdout() as args.json_out:
                return int(args.handler(args))
        args.json_out = sys.stdout
        return int(args.handler(args))
    except HolousdError as exc:
        _traceback(verbose)
        print(f"{prefix}: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:
        _traceback(verbose)
        print(f"{prefix}: error: {describe_os_error(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _traceback(verbose)
        print(f"{prefix}: interrupted; no file was left half-written", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug: one line, the traceback on request
        _traceback(verbose)
        print(f"{prefix}: internal error ({type(exc).__name__}: {_one_line(str(exc))}); no file was left "
              "half-written; re-run with --verbose and report the traceback", file=sys.stderr)  # fmt: skip
        return EXIT_INTERNAL


_FILE_OUTPUTS = {("simulate", "out"), ("export", "sim"), ("export", "usdz")}
"""(command, option) pairs whose path is a file; every other ``--out`` / ``OUT`` is a folder."""


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse an output path that cannot be written (a file where a folder goes, a read-only folder, ...) before
    the command starts any work; nothing is created here."""
    from holousd._paths import output_file, output_folder

    for dest in ("out", "sim", "usdz"):
        value = getattr(args, dest, None)
        if not isinstance(value, os.PathLike):
            continue
        if (args.command, dest) in _FILE_OUTPUTS:
            output_file(value, f"--{dest} file", create=False)
        else:
            output_folder(value, "output folder", create=False)


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _traceback(verbose: bool) -> None:
    if verbose:
        import traceback

        traceback.print_exc(file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
