"""Argument builders shared by every command, so a flag means the same thing everywhere."""
from __future__ import annotations

import argparse


class CommandError(Exception):
    """A failure the user causes or can fix (flags, files, data, missing packages, a run that
    diverged): ``mcdenoise`` prints it as one line and exits with status 2, no traceback.
    Library errors of that kind subclass it (beside their usual base, e.g. RuntimeError)."""


def parse_size(text: str) -> tuple[int, int]:
    """"WxH" -> (width, height) in pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 256x256, got {text!r}") from None
    if w < 8 or h < 8:
        raise argparse.ArgumentTypeError(f"size must be at least 8x8, got {text!r}")
    return w, h


#: What each shared flag means, the same in every command that takes it (a command adds only
#: what it draws, which folder it defaults to, or its default).
SHARED_HELP = {
    "--size": "image width x height in pixels",
    "--seed": "random seed of every draw this command makes; the same seed and flags give the same result",
    "--data": "folder of sequences written by 'mcdenoise render'",
    "--threads": "CPU threads for torch/onnxruntime (0: library default)",
}


def add_size(p: argparse.ArgumentParser, default: str = "256x256") -> None:
    p.add_argument("--size", type=parse_size, default=parse_size(default), metavar="WxH",
                   help=f"{SHARED_HELP['--size']} (default {default})")


def add_seed(p: argparse.ArgumentParser, draws: str, default: int = 0) -> None:
    """``--seed``; ``draws`` says what the command draws from it."""
    p.add_argument("--seed", type=int, default=default, help=f"{SHARED_HELP['--seed']} (here: {draws}; default {default})")


def add_data(p: argparse.ArgumentParser, required: bool = True, default: str | None = None) -> None:
    """``--data``; ``default`` describes what an optional one falls back to."""
    note = f" (default: {default})" if default else ""
    p.add_argument("--data", required=required, metavar="DIR", help=SHARED_HELP["--data"] + note)


def add_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=int, default=0, help=SHARED_HELP["--threads"])
