"""mcdenoise: real-time neural denoisers for Monte Carlo path-traced images.

One import namespace over the checkout's folders: ``mcdenoise.runtime`` (``runtime/``: numpy,
onnxruntime and OpenEXR only, never torch), ``mcdenoise.training`` (``training/``) and
``mcdenoise.export`` (``export/``). The shipped models, model cards, specs and the sample
sequence are package data: :func:`mcdenoise.runtime.data_path` finds them.
"""
__version__ = "0.1.0"
