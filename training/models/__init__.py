"""Model builders, and the interface every mcdenoise model follows.

Importing this package imports torch and registers every builder with
:func:`training.specs.register`; :func:`training.specs.build_model` imports it for you.

The model interface
-------------------
A model is a ``torch.nn.Module`` with

``input_names: tuple[str, ...]`` and ``output_names: tuple[str, ...]``
    exactly :attr:`training.specs.ModelSpec.input_names` / ``output_names`` of its spec.
``forward(*tensors) -> tuple``
    float32 NCHW tensors in ``input_names`` order; returns a tuple in ``output_names`` order.
    Inputs:

    * the spec's pixel layers, by :data:`runtime.frames.PIXEL_LAYERS` name:
      ``color`` (N, 3, H, W) linear HDR radiance, already sanitised (finite, >= 0);
      ``albedo`` (N, 3, H, W), >= 0 (0 on misses and delta BSDFs, may exceed 1);
      ``normal`` (N, 3, H, W) unit normals in [-1, 1] in the camera's screen-aligned frame
      (x right, y down, z forward; :func:`runtime.inputs.screen_normals`), 0 on a miss;
      ``depth`` (N, 1, H, W) distance from the camera centre in scene units (0 on a miss);
    * per ``[[state]]`` entry ``prev_<name>`` (N, C, H, W): the previous frame's
      ``next_<name>`` output, reprojected to this frame by the driver (finite; zeros where
      there is no history);
    * ``history`` (N, 1, H, W) in [0, 1], present iff the spec has state: the driver's
      reprojection-validity mask, 0 on the first frame, after a reset and where disoccluded.

    Outputs: ``output`` (N, 3, H, W) linear HDR radiance, then ``next_<name>`` per state entry.
    N, H and W are free (the export makes them dynamic axes).
``state_channels: dict[str, int]``
    state name -> channel count, as in the spec's ``[[state]]``.
one child module per spec stage, named after it (``model.temporal``, ``model.prediction``...)
    and nothing else at the top level: every operation of ``forward`` runs inside a stage
    module, so exported node names start with ``/<stage>/`` and the runtime can split a
    profile into stages.  Pre-processing (tonemapping, normalisation, demodulation) lives
    inside a stage too.
``deploy() -> nn.Module``
    the inference form with the same interface (eval mode, re-parameterised layers fused,
    fastest equivalent code path); the exporter exports ``model.deploy()``.

Training calls ``model.train()`` / ``model.eval()`` as usual; the builders are in the modules
of this package (``wskpn``: WSKPN; ``nbg``: neural bilateral grid; ``anf``: affinity of neural features;
``ndle``: layer embeddings), with the pieces they
share (albedo demodulation, temporal accumulation, network features) in ``common``.
"""
from __future__ import annotations

import numpy as np

from mcdenoise.runtime.contract import SAMPLES_INPUT
from mcdenoise.runtime.inputs import sample_group_channels
from mcdenoise.runtime.temporal import Protocol
from mcdenoise.training.models import anf  # noqa: F401  (registers type "anf")
from mcdenoise.training.models import nbg  # noqa: F401  (registers type "nbg")
from mcdenoise.training.models import ndle  # noqa: F401  (registers type "ndle")
from mcdenoise.training.models import wskpn  # noqa: F401  (registers type "wskpn")


def example_inputs(model, n: int = 1, h: int = 32, w: int = 48, seed: int = 0, spp: int = 4) -> dict[str, np.ndarray]:
    """Plausible random float32 inputs for ``model`` (by its ``input_names``), for tests and
    export checks: name -> (n, C, h, w) array; a per-sample model's ``samples`` (n, spp, F, h, w)
    and its settings (int64 scalars at their defaults, ``model.settings``).

    color: smooth HDR radiance times 1-spp-like noise (heavy-tailed, with a few fireflies up
    to ~100); albedo in [0, 1] with a few 0 (miss) pixels; normal: unit vectors (0 where
    depth is 0); depth in [0.5, 20] with ~3% misses (0); emissive (when the model reads it): 90% 0,
    5% 1, 5% fractions; prev_<state>: like color; history:
    a mix of 0, 1 and fractions.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    base = (0.5 + 0.4 * np.sin(6.0 * xx + 3.0 * yy))[None, None]

    def radiance(c: int) -> np.ndarray:
        noise = rng.exponential(1.0, size=(n, c, h, w))
        fireflies = (rng.random((n, 1, h, w)) < 0.005) * rng.uniform(10.0, 100.0, (n, 1, h, w))
        return base * noise + fireflies

    miss = rng.random((n, 1, h, w)) < 0.03
    layers = {
        "color": radiance(3),
        "albedo": np.where(miss, 0.0, rng.uniform(0.0, 1.0, (n, 3, h, w))),
        "depth": np.where(miss, 0.0, rng.uniform(0.5, 20.0, (n, 1, h, w))),
    }
    nrm = rng.normal(size=(n, 3, h, w))
    layers["normal"] = np.where(miss, 0.0, nrm / np.linalg.norm(nrm, axis=1, keepdims=True))
    if "emissive" in model.input_names:     # drawn only then: the other models' inputs stay as they were
        u = rng.random((n, 1, h, w))
        layers["emissive"] = np.where(u < 0.9, 0.0, np.where(u > 0.95, 1.0, rng.random((n, 1, h, w))))
    protocol = Protocol.from_spec(model.state_channels)
    if protocol.state:
        hist = rng.random((n, 1, h, w))
        layers[protocol.history] = np.where(hist < 0.3, 0.0, np.where(hist > 0.6, 1.0, hist))
    layers.update({inp: radiance(ch) for _, inp, _, ch in protocol.state})
    # a state's fed blend weight: (n, 1, 1, 1) in (0, 1]
    layers.update({inp: rng.uniform(0.1, 1.0, (n, 1, 1, 1)) for inp in getattr(model, "state_weights", {})})
    groups = getattr(model, "sample_groups", ())
    if groups:
        layers[SAMPLES_INPUT] = np.concatenate([_sample_group(rng, g, (n, spp, h, w), radiance) for g, _ in groups], axis=2)
    out = {}
    for name in model.input_names:
        if name in layers:
            out[name] = np.ascontiguousarray(layers[name], dtype=np.float32)
        elif name in getattr(model, "settings", {}):
            out[name] = np.array(model.settings[name], np.int64)
        else:
            raise KeyError(f"example_inputs: no generator for input {name!r}")
    return out


def _sample_group(rng, group: str, shape, radiance) -> np.ndarray:
    """Random per-sample values of ``group``: (N, S, C, H, W)."""
    n, s, h, w = shape
    c = sample_group_channels(group)
    if "radiance" in group:
        return radiance(s * c).reshape(n, s, c, h, w)
    if group == "normal":
        v = rng.normal(size=(n, s, 3, h, w))
        return v / np.linalg.norm(v, axis=2, keepdims=True)
    if group == "depth":
        return rng.uniform(0.5, 20.0, (n, s, 1, h, w))
    if group in ("roughness", "albedo", "specular_color"):
        return rng.uniform(0.0, 1.0, (n, s, c, h, w))
    return (rng.random((n, s, c, h, w)) < 0.2).astype(np.float64)     # flags
