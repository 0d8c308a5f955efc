"""``mcdenoise`` console script: a thin dispatcher over library functions.

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and
``main(args) -> int``; the module is imported only when its command runs, so
``mcdenoise denoise`` works on a machine with no torch or Mitsuba installed.
Flags shared by several commands are defined once in :mod:`runtime.args`.
"""
from __future__ import annotations

import argparse
import importlib
import sys

#: command -> (module, one-line help).  The module provides add_arguments() and main().
COMMANDS: dict[str, tuple[str, str]] = {
    "render": ("training.render.command", "render per-sample training/test sequences with Mitsuba 3"),
    "inspect": ("runtime.inspect", "print what a frame EXR file holds"),
    "train": ("training.train", "train a model spec on rendered data into a run folder"),
    "export": ("export.onnx_export", "export a run folder to a self-describing ONNX file"),
    "denoise": ("runtime.denoise", "denoise a frame sequence with an ONNX model, print stage timings"),
    "evaluate": ("training.evaluate", "score ONNX models, Open Image Denoise and the noisy input on held-out sequences"),
    "bench": ("training.bench", "benchmark models: per-stage time (torch vs onnxruntime) and quality"),
    "stress": ("training.stress", "error increase of every method on fireflies, NaN/Inf, cuts, defocus, motion blur, exposure..."),
}


class CommandError(Exception):
    """A user-facing error: printed as one line, exit status 2, no traceback."""


def build_parser(name: str) -> tuple[argparse.ArgumentParser, object]:
    module_name, help_text = COMMANDS[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        raise CommandError(f"'mcdenoise {name}' needs the Python package {e.name!r}; "
                           f"install it (see README, set-up)") from None
    parser = argparse.ArgumentParser(prog=f"mcdenoise {name}", description=help_text)
    module.add_arguments(parser)
    return parser, module


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        width = max(map(len, COMMANDS))
        print("usage: mcdenoise <command> [options]\n\ncommands:")
        for n, (_, h) in COMMANDS.items():
            print(f"  {n:<{width}}  {h}")
        if argv and argv[0] not in ("-h", "--help"):
            print(f"\nmcdenoise: unknown command {argv[0]!r}", file=sys.stderr)
            return 2
        return 0
    from runtime.frames import FrameError

    try:
        parser, module = build_parser(argv[0])
        args = parser.parse_args(argv[1:])
        return int(module.main(args) or 0)
    except (CommandError, FrameError, FileNotFoundError, FileExistsError, ValueError) as e:
        print(f"mcdenoise {argv[0]}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mcdenoise {argv[0]}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
