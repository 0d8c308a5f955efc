"""``mcdenoise inspect FILE...``: print the layers, statistics and metadata of frame files."""
from __future__ import annotations

from mcdenoise.runtime.frames import describe


def add_arguments(p):
    p.add_argument("files", nargs="+", help="frame EXR files")


def main(args) -> int:
    for path in args.files:
        print(describe(path))
    return 0
