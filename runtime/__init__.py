"""mcdenoise runtime: numpy + onnxruntime + OpenEXR only (never torch)."""
__version__ = "0.1.0"
