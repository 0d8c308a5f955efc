"""``mcdenoise`` console script: a thin dispatcher over library functions.

Each subcommand lives in its own module exposing ``add_arguments(parser)`` and
``main(args) -> int``; the module is imported only when its command runs, so
``mcdenoise denoise`` works on a machine with no torch or Mitsuba installed.
Flags shared by several commands are defined once in :mod:`runtime.args`.
"""
from __future__ import annotations

import argparse
import importlib
import os
import shlex
import sys

from mcdenoise.runtime.args import CommandError

#: command -> (module, one-line help).  The module provides add_arguments() and main().
COMMANDS: dict[str, tuple[str, str]] = {
    "render": ("mcdenoise.training.render.command", "render per-sample training/test sequences with Mitsuba 3"),
    "inspect": ("mcdenoise.runtime.inspect", "print what a frame EXR file holds"),
    "train": ("mcdenoise.training.train", "train a model spec on rendered data into a run folder"),
    "export": ("mcdenoise.export.onnx_export", "export a run folder to a self-describing ONNX file"),
    "denoise": ("mcdenoise.runtime.denoise", "denoise a frame sequence with an ONNX model, print stage timings"),
    "evaluate": ("mcdenoise.training.evaluate", "score ONNX models, Open Image Denoise and the noisy input on held-out sequences"),
    "sweep": ("mcdenoise.training.sweep", "quality and time against a run-time setting (ANF's kernel size, Fig. 7)"),
    "curves": ("mcdenoise.training.curves", "learning curves: test PSNR against examples seen, by data size and a spec value"),
    "bench": ("mcdenoise.training.bench", "benchmark models: per-stage time (torch vs onnxruntime) and quality"),
    "stress": ("mcdenoise.training.stress", "error increase of every method on fireflies, NaN/Inf, cuts, defocus, motion blur, exposure..."),
}


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


def command_line(name: str, args: argparse.Namespace) -> str:
    """The canonical command line of ``args`` for ``mcdenoise <name>`` (what output files
    record): the positionals, then every flag whose value differs from its default, in the
    parser's order; absolute paths under the current directory relative to it."""
    parser, _ = build_parser(name)

    def show(v) -> str:
        if isinstance(v, tuple):  # a --size already parsed to (width, height)
            return "x".join(map(str, v))
        v = str(v)
        if os.path.isabs(v) and v.startswith(os.getcwd().rstrip(os.sep) + os.sep):
            v = os.path.relpath(v)
        return v

    parts = ["mcdenoise", name]
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        v = getattr(args, action.dest, None)
        if not action.option_strings:
            parts += [show(x) for x in (v if isinstance(v, list) else [v]) if x is not None]
        elif v != action.default and not (isinstance(v, list) and list(v) == list(action.default or [])):
            flag = max(action.option_strings, key=len)
            if action.nargs == 0:
                parts.append(flag)
            elif isinstance(v, list):
                parts += [flag, *map(show, v)]
            else:
                parts += [flag, show(v)]
    return " ".join(shlex.quote(p) for p in parts)


def _one_line(e: BaseException) -> str:
    """The message of ``e`` on one line (an OSError without a message gets its class name)."""
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 2000 else text[:2000] + " ..."


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
    from mcdenoise.runtime.frames import FrameError

    try:
        parser, module = build_parser(argv[0])
        args = parser.parse_args(argv[1:])
        try:
            return int(module.main(args) or 0)
        except ModuleNotFoundError as e:  # a package imported where the command first needs it
            if (e.name or "mcdenoise").split(".")[0] == "mcdenoise":
                raise
            raise CommandError(f"'mcdenoise {argv[0]}' needs the Python package {e.name!r}; "
                               f"install it (see README, set-up)") from None
    except (CommandError, FrameError, OSError, ValueError, MemoryError) as e:
        # MemoryError: train's cache check says what to do; numpy's names the allocation
        print(f"mcdenoise {argv[0]}: error: {_one_line(e) or type(e).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mcdenoise {argv[0]}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    code = main()
    if int(os.environ.get("WORLD_SIZE", "1") or 1) > 1:
        # A process torchrun started has left its group (training/train.py) and written its
        # files; the interpreter's teardown can still abort in gloo's threads ("terminate
        # called without an active exception", exit -6: seen once in CI), so it ends here.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
