"""mcdenoise runtime: numpy + onnxruntime + OpenEXR only (never torch)."""
from __future__ import annotations

from pathlib import Path

#: Where the shipped data folders (``models/``, ``models_spec/``, ``samples/``) live: beside
#: this package, in the installed ``mcdenoise`` package (wheel) and in the checkout alike
#: (an editable install maps ``mcdenoise.runtime`` to ``runtime/``).
DATA_ROOT = Path(__file__).resolve().parent.parent


def data_path(*parts: str) -> Path:
    """Path of shipped data, e.g. ``data_path("models", "wskpn-3.onnx")``; it may not exist."""
    return DATA_ROOT.joinpath(*parts)
