"""argparse helpers shared by the sub-commands: ``type=`` callables and the help formatter."""

from __future__ import annotations

import argparse
import json
import sys
import textwrap

__all__ = ["HelpFormatter", "emit_json", "positive_int", "resolution"]


def emit_json(args: argparse.Namespace, data: object) -> None:
    """Print a ``--json`` command's result: to the real stdout the CLI set aside (``args.json_out``), where
    nothing else lands while the command runs (see ``holousd.cli``); to ``sys.stdout`` otherwise."""
    print(json.dumps(data, indent=2), file=getattr(args, "json_out", None) or sys.stdout)


class HelpFormatter(argparse.HelpFormatter):
    """Wrap the prose of descriptions and epilogs to the terminal, keep indented lines (tables, lists) as written,
    and show each option's default where it has one worth saying.

    Defaults are left out for required options, options without a default (None), on/off flags (False), and
    options whose help already says what the default is. A ``WxH`` size shows as ``160x120``.
    """

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        out: list[str] = []
        paragraph: list[str] = []

        def flush() -> None:
            if paragraph:
                out.append(textwrap.fill(" ".join(paragraph), width, initial_indent=indent, subsequent_indent=indent))
                paragraph.clear()

        for line in text.splitlines():
            if not line.strip() or line[:1].isspace():  # blank, or indented (a table row, a list): as written
                flush()
                out.append(indent + line if line.strip() else "")
                continue
            paragraph.append(line.strip())
            if line.rstrip().endswith(":"):  # a heading of what follows
                flush()
        flush()
        return "\n".join(out)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (action.required or default is None or default is False or default is argparse.SUPPRESS
                or "default" in text or "%(default)" in text):  # fmt: skip
            return text
        if action.metavar == "WxH" and isinstance(default, tuple) and len(default) == 2:
            return f"{text} (default: {default[0]}x{default[1]})"
        return f"{text} (default: %(default)s)"


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def resolution(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` in pixels, 16..4096 per side."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 320x240, got {text!r}") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"resolution {w}x{h} out of range; use 16..4096 pixels per side")
    return w, h
