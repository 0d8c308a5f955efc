"""Argument builders shared by every command, so a flag means the same thing everywhere."""
from __future__ import annotations

import argparse


def parse_size(text: str) -> tuple[int, int]:
    """"WxH" -> (width, height) in pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 256x256, got {text!r}") from None
    if w < 8 or h < 8:
        raise argparse.ArgumentTypeError(f"size must be at least 8x8, got {text!r}")
    return w, h


def add_size(p: argparse.ArgumentParser, default: str = "256x256") -> None:
    p.add_argument("--size", type=parse_size, default=parse_size(default), metavar="WxH",
                   help=f"image width x height in pixels (default {default})")


def add_seed(p: argparse.ArgumentParser, default: int = 0) -> None:
    p.add_argument("--seed", type=int, default=default, help=f"base random seed (default {default})")


def add_data(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("--data", required=required, metavar="DIR",
                   help="dataset folder written by 'mcdenoise render'")


def add_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=int, default=0,
                   help="CPU threads for torch/onnxruntime (0: library default)")
