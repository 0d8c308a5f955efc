"""Pieces shared by several model types (import torch).

Defined here once so that every model demodulates, accumulates and builds its network input
the same way (STYLE: no magic constant in ten files):

* :data:`ALBEDO_EPS` (from :mod:`runtime.inputs`), :func:`demodulate` / :func:`remodulate` and
  :func:`modulation_albedo`: albedo (de)modulation;
* :func:`temporal_accumulate` (:func:`runtime.temporal.accumulate`, defined there for the driver
  too) and :class:`TemporalStage`: the exponential moving average with the driver's
  reprojected history (WSKPN §4.1, NBG §4.6: decay 0.2), for models that accumulate in-graph;
* :func:`aux_features`: the 10-channel network input [transfer(colour), albedo, normal, depth];
* :func:`conv3` and :func:`eval_copy`: the U-Nets' 3×3 convolution with leaky ReLU, and the
  inference form of a model with nothing to fuse;
* :class:`SampleEmbedding`: the per-sample MLP over the ``samples`` input (ANF Eq. 1, NDLE's
  sample reducer), its features each group through its transfer;
* :func:`accum_interface`, :func:`bind_inputs`, :func:`check_accum_state`,
  :func:`check_accum_model_spec`: the model-interface bookkeeping of a model whose only state
  is the accumulated radiance.
"""
from __future__ import annotations

import torch
from torch import nn

from mcdenoise.runtime.contract import HISTORY, OUTPUT, state_input_name, state_output_name
from mcdenoise.runtime.inputs import ALBEDO_EPS  # noqa: F401  (defined in runtime: SVGF uses it too)
from mcdenoise.runtime.inputs import sample_group_channels
from mcdenoise.runtime.temporal import accumulate as temporal_accumulate  # noqa: F401  (the driver blends too)
from mcdenoise.runtime.transfer import get as get_transfer

#: Slope of the leaky ReLUs of the per-sample networks (ANF does not give it: torch's default;
#: NDLE App. B: 0.01).
LEAK = 0.01

#: State name of the accumulated-radiance temporal state (WSKPN §4.1, NBG §4.6).
ACCUM = "accum"


def demodulate(color: torch.Tensor, albedo: torch.Tensor) -> torch.Tensor:
    """Irradiance (N, 3, H, W) = color / (albedo + ALBEDO_EPS); both (N, 3, H, W), >= 0."""
    return color / (albedo + ALBEDO_EPS)


def emitter_albedo(albedo: torch.Tensor, emissive: torch.Tensor | None) -> torch.Tensor:
    """The albedo a model that reads the ``emissive`` layer (de)modulates by: ``albedo`` where no
    sample hit a light, 1 where all did, the coverage-weighted mix between (N, 3, H, W).
    A light's own albedo is 0, so demodulating by it gives colour / ALBEDO_EPS, 100x the light's
    radiance, which a kernel spreads into its neighbours as a halo (docs/results/retrain).
    ``emissive``: (N, 1, H, W) fraction in [0, 1] (clamped: the layer is not sanitised to a
    range); None leaves ``albedo`` as it is."""
    if emissive is None:
        return albedo
    e = emissive.clamp(0.0, 1.0)
    return albedo + e * (1.0 - albedo)


def dark_albedo(albedo: torch.Tensor, dark: float) -> torch.Tensor:
    """``albedo`` (N, 3, H, W) >= 0 blended toward 1 where it is dark: m = d·albedo + (1 − d),
    d = min(max_c albedo / ``dark``, 1).  Misses, mirrors and glass have an albedo of 0, so
    demodulating by it gives colour / ALBEDO_EPS, 100x their radiance; a filter whose
    weights do not know that spreads it into its neighbours as a halo (docs/results/anf-demod).
    With this the irradiance is colour / (albedo + ε) from ``dark`` up, and below it goes
    down to the colour itself at an albedo of 0: at most 1 / ``dark`` times the colour."""
    d = (albedo.amax(dim=1, keepdim=True) / dark).clamp(max=1.0)
    return albedo * d + (1.0 - d)


def modulation_albedo(albedo: torch.Tensor, emissive: torch.Tensor | None = None,
                      clamp: bool = False, dark: float = 0.0) -> torch.Tensor:
    """The albedo a model (de)modulates by, (N, 3, H, W): ``albedo`` clamped to [0, 1] when
    ``clamp`` (Mitsuba's albedo AOV of a rough conductor reaches 58, and re-modulating a
    filtered irradiance by it turns a firefly into a blotch: docs/results/scale), blended
    toward 1 below ``dark`` when it is > 0 (:func:`dark_albedo`), then :func:`emitter_albedo`
    with ``emissive``. With none of them it is ``albedo`` itself, as the models without these
    options were trained."""
    m = albedo.clamp(0.0, 1.0) if clamp else albedo
    return emitter_albedo(dark_albedo(m, dark) if dark > 0 else m, emissive)


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
                 depth: torch.Tensor, transfer: str, emissive: torch.Tensor | None = None) -> torch.Tensor:
    """Network input (WSKPN §5.1, NBG §5): (N, 10, H, W) =
    [transfer(color) (3), albedo (3), normal·0.5+0.5 in [0, 1] (3), depth / per-image max (1)],
    and with ``emissive`` (N, 1, H, W) the 11th channel, that fraction clamped to [0, 1].

    color: linear HDR radiance (albedo-modulated, as rendered); normal: unit vectors (0 on a
    miss -> 0.5); depth: ray distance, 0 on a miss.  Dividing by the per-image maximum keeps the
    feature in [0, 1] whatever the scene units (the papers scale linearly to [0, 1]); a crop's
    maximum differs from its frame's, which training crops must live with.
    """
    dmax = depth.amax(dim=(1, 2, 3), keepdim=True).clamp(min=1e-12)
    extra = [] if emissive is None else [emissive.clamp(0.0, 1.0)]
    return torch.cat([get_transfer(transfer)(color), albedo, normal * 0.5 + 0.5, depth / dmax] + extra, dim=1)


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


def check_accum_model_spec(spec, type_name: str, layers, stages, optional=()) -> bool:
    """Validate the parts of ``spec`` every accumulated-radiance model checks the same way:
    ``[inputs].layers`` are ``layers`` (any order) plus any of ``optional``, ``stages`` are ``stages`` with an optional
    leading "temporal", and ``[[state]]`` fits (:func:`check_accum_state`).  Raises SpecError
    naming the spec; returns whether the model has the temporal stage."""
    from mcdenoise.training.specs import SpecError

    where = spec.path or spec.name
    extra = sorted(set(spec.inputs.layers) - set(layers))
    if sorted(set(spec.inputs.layers) - set(extra)) != sorted(layers) or not set(extra) <= set(optional):
        also = f", optionally with {list(optional)}" if optional else ""
        raise SpecError(f"{where}: [inputs].layers must be {list(layers)} (any order){also} for type "
                        f"'{type_name}', got {list(spec.inputs.layers)}")
    temporal = "temporal" in spec.stages
    want = (("temporal",) if temporal else ()) + tuple(stages)
    if tuple(spec.stages) != want:
        raise SpecError(f"{where}: stages must be {list(want)} for type '{type_name}', got {list(spec.stages)}")
    check_accum_state(spec, temporal, where, type_name)
    return temporal


def conv3(cin: int, cout: int, act: bool = True) -> nn.Module:
    """A 3×3 convolution (zero padding 1), followed by a leaky ReLU (:data:`LEAK`) if ``act``."""
    conv = nn.Conv2d(cin, cout, 3, padding=1)
    return nn.Sequential(conv, nn.LeakyReLU(LEAK)) if act else conv


def eval_copy(model: nn.Module) -> nn.Module:
    """``deploy()`` of a model with nothing to fuse: a copy in eval mode."""
    import copy

    return copy.deepcopy(model).eval()


class SampleEmbedding(nn.Module):
    """A per-sample MLP: ``layers`` 1×1 convolutions of ``width`` channels with leaky ReLUs on
    each sample's features (ANF §3.1 Eq. 1, NDLE App. B "sample reducer": 3 layers of 32).

    ``groups``: (group, transfer) of the ``samples`` input's channels, in order (the spec's
    ``[inputs].samples``)."""

    def __init__(self, groups: tuple[tuple[str, str], ...], width: int, layers: int):
        super().__init__()
        self.groups = groups
        cin = sum(sample_group_channels(g) for g, _ in groups)
        mods = []
        for i in range(layers):
            mods += [nn.Conv2d(cin if i == 0 else width, width, 1), nn.LeakyReLU(LEAK)]
        self.mlp = nn.Sequential(*mods)
        self.width = width

    def features(self, samples: torch.Tensor) -> torch.Tensor:
        """The MLP's input (N, S, F, H, W): each group through its transfer, depth divided by
        the frame's largest sample depth (scene units vary; the papers scale to [0, 1])."""
        parts, c = [], 0
        for group, transfer in self.groups:
            n = sample_group_channels(group)
            x = samples[:, :, c:c + n]
            if group == "depth":
                x = x / x.amax(dim=(1, 2, 3, 4), keepdim=True).clamp(min=1e-12)
            parts.append(get_transfer(transfer)(x))
            c += n
        return torch.cat(parts, dim=2)

    def per_sample(self, samples: torch.Tensor, multiple: int = 1) -> torch.Tensor:
        """samples (N, S, F, H, W): linear, sanitised, exposed (runtime.inputs.sample_inputs) ->
        each sample's embedding (N·S, E, H', W'), H' and W' replicate-padded up to a multiple of
        ``multiple`` (the MLP is per pixel, so padding first equals padding after)."""
        from mcdenoise.training.models.wskpn import pad_to_multiple

        x = self.features(samples)
        n, s, c, h, w = x.shape
        # reshape with the traced sizes (``unflatten`` bakes the traced H, W into the graph)
        x = x.reshape(n * s, c, h, w)
        return self.mlp(pad_to_multiple(x, multiple) if multiple > 1 else x)

    def forward(self, samples: torch.Tensor) -> torch.Tensor:
        """samples (N, S, F, H, W) -> e (N, E, H, W), the mean over S of the per-sample MLP."""
        n, s, h, w = samples.shape[0], samples.shape[1], samples.shape[3], samples.shape[4]
        return self.per_sample(samples).reshape(n, s, self.width, h, w).mean(dim=1)
