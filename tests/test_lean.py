"""The deployable runtime stays small and self-contained: the core a game or renderer imports
reads in one sitting, and imports nothing but itself, numpy, onnxruntime and OpenEXR (the
measuring side, training and export live apart from it)."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

RUNTIME = Path(__file__).resolve().parent.parent / "runtime"
#: The deployable core (ARCHITECTURE: frames, inputs, contract, temporal, denoiser, timing),
#: with the transfer curves and the driver's worker threads.
CORE = ("__init__", "frames", "inputs", "contract", "temporal", "denoiser", "timing", "transfer", "workers",
        "prelude")
#: Lines of the core, blank lines and comments included.
LINE_BUDGET = 2500
ALLOWED = {"numpy", "onnxruntime", "OpenEXR", "mcdenoise"}


def test_the_core_fits_its_line_budget():
    lines = {m: len((RUNTIME / f"{m}.py").read_text().splitlines()) for m in CORE}
    assert sum(lines.values()) <= LINE_BUDGET, lines


def test_the_core_imports_only_itself_numpy_onnxruntime_and_openexr():
    stdlib = set(sys.stdlib_module_names)
    for m in CORE:
        tree = ast.parse((RUNTIME / f"{m}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                # ``from mcdenoise.runtime import x``: x is a module of the package or a name of
                # its __init__ (data_path)
                names = [f"{node.module}.{a.name}" if node.module == "mcdenoise.runtime" and a.name in
                         {p.stem for p in RUNTIME.glob("*.py")} else node.module for a in node.names]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top in stdlib or top in ALLOWED, f"runtime/{m}.py imports {name}"
                if top == "mcdenoise":
                    part = name.split(".")
                    assert part[:2] == ["mcdenoise", "runtime"] and (len(part) == 2 or part[2] in CORE), \
                        f"runtime/{m}.py imports {name}, outside the core"
