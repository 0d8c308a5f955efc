"""Pieces shared by several model types (import torch).

Defined here once so that every model demodulates, accumulates and builds its network input
the same way (STYLE: no magic constant in ten files):

* :data:`ALBEDO_EPS` (from :mod:`runtime.inputs`) and :func:`demodulate` / :func:`remodulate`: albedo (de)modulation;
* :func:`temporal_accumulate` (:func:`runtime.temporal.accumulate`, defined there for the driver
  too) and :class:`TemporalStage`: the exponential moving average with the driver's
  reprojected history (WSKPN §4.1, NBG §4.6: decay 0.2), for models that accumulate in-graph;
* :func:`aux_features`: the 10-channel network input [transfer(colour), albedo, normal, depth];
* :func:`accum_interface`, :func:`bind_inputs`, :func:`check_accum_state`,
  :func:`check_accum_model_spec`: the model-interface bookkeeping of a model whose only state
  is the accumulated radiance.
"""
from __future__ import annotations

import torch
from torch import nn

from mcdenoise.runtime.contract import HISTORY, OUTPUT, state_input_name, state_output_name
from mcdenoise.runtime.inputs import ALBEDO_EPS  # noqa: F401  (defined in runtime: SVGF uses it too)
from mcdenoise.runtime.temporal import accumulate as temporal_accumulate  # noqa: F401  (the driver blends too)
from mcdenoise.runtime.transfer import get as get_transfer

#: State name of the accumulated-radiance temporal state (WSKPN §4.1, NBG §4.6).
ACCUM = "accum"


def demodulate(color: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """Irradiance (N, 3, H, W) = color / (albedo + ALBEDO_EPS); both (N, 3, H, W), >= 0."""
    return color / (albedo + ALBEDO_EPS)


def remodulate(irradiance: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`demodulate`: irradiance · (albedo + ALBEDO_EPS)."""
    return irradiance * (albedo + ALBEDO_EPS)


class TemporalStage(nn.Module):
    """Stage "temporal": :func:`temporal_accumulate` with a fixed α."""

    def __init__(self, alpha: float):
        super().__init__()
        self.alpha = float(alpha)

    def forward(self, color, prev, history):
        return temporal_accumulate(color, prev, history, self.alpha)


def aux_features(color: torch.Tensor, albedo: torch.Tensor, normal: torch.Tensor,
                 depth: torch.Tensor, transfer: str) -> torch.Tensor:
    """Network input (WSKPN §5.1, NBG §5): (N, 10, H, W) =
    [transfer(color) (3), albedo (3), normal·0.5+0.5 in [0, 1] (3), depth / per-image max (1)].

    color: linear HDR radiance (albedo-modulated, as rendered); normal: unit vectors (0 on a
    miss -> 0.5); depth: ray distance, 0 on a miss.  Dividing by the per-image maximum keeps the
    feature in [0, 1] whatever the scene units (the papers scale linearly to [0, 1]); a crop's
    maximum differs from its frame's, which training crops must live with.
    """
    dmax = depth.amax(dim=(1, 2, 3), keepdim=True).clamp(min=1e-12)
    return torch.cat([get_transfer(transfer)(color), albedo, normal * 0.5 + 0.5, depth / dmax], dim=1)


def accum_interface(layers, temporal: bool):
    """(state_channels, input_names, output_names) of a model on frame ``layers`` whose only
    temporal state, when ``temporal``, is :data:`ACCUM` (3 channels) plus the history mask."""
    state_in = (state_input_name(ACCUM), HISTORY) if temporal else ()
    return ({ACCUM: 3} if temporal else {}, tuple(layers) + state_in,
            (OUTPUT,) + ((state_output_name(ACCUM),) if temporal else ()))


def bind_inputs(model: nn.Module, inputs) -> dict:
    """``forward(*inputs)``'s tensors by ``model.input_names``; TypeError on a wrong count."""
    if len(inputs) != len(model.input_names):
        raise TypeError(f"{type(model).__name__}.forward takes {len(model.input_names)} tensors "
                        f"{model.input_names}, got {len(inputs)}")
    return dict(zip(model.input_names, inputs))


def check_accum_state(spec, temporal: bool, where: str, type_name: str) -> None:
    """SpecError unless ``spec``'s [[state]] is exactly the accumulated radiance when it has a
    temporal stage, and empty otherwise."""
    from mcdenoise.training.specs import SpecError

    state = [(s.name, s.channels) for s in spec.state]
    want = [(ACCUM, 3)] if temporal else []
    if state != want:
        raise SpecError(f"{where}: [[state]] must be {want} for type '{type_name}' "
                        f"({'with' if temporal else 'without'} a temporal stage), got {state}")


def check_accum_model_spec(spec, type_name: str, layers, stages) -> bool:
    """Validate the parts of ``spec`` every accumulated-radiance model checks the same way:
    ``[inputs].layers`` are ``layers`` (any order), ``stages`` are ``stages`` with an optional
    leading "temporal", and ``[[state]]`` fits (:func:`check_accum_state`).  Raises SpecError
    naming the spec; returns whether the model has the temporal stage."""
    from mcdenoise.training.specs import SpecError

    where = spec.path or spec.name
    if sorted(spec.inputs.layers) != sorted(layers):
        raise SpecError(f"{where}: [inputs].layers must be {list(layers)} (any order) for type "
                        f"'{type_name}', got {list(spec.inputs.layers)}")
    temporal = "temporal" in spec.stages
    want = (("temporal",) if temporal else ()) + tuple(stages)
    if tuple(spec.stages) != want:
        raise SpecError(f"{where}: stages must be {list(want)} for type '{type_name}', got {list(spec.stages)}")
    check_accum_state(spec, temporal, where, type_name)
    return temporal
