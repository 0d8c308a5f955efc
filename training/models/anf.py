"""ANF: affinity of neural features (Işık et al., SIGGRAPH 2021), registered as type "anf".

Pipeline (stages, in order; each is a submodule so exported node names carry its prefix):

``embedding`` (§3.1-3.2, Eq. 1)
    each sample's features r (the spec's ``[inputs].samples`` groups, each through its
    transfer: log(1+x) on the diffuse and specular radiance; depth divided by the frame's
    largest sample depth) -> a per-sample MLP (``embed_layers`` 1×1 convolutions of
    ``embed_width`` channels, leaky ReLU) on the samples reshaped into the batch, averaged over
    the S samples: e (N, E, H, W).  The only stage whose cost grows with S.
``unet`` (§3.3, Eq. 2)
    a U-Net on [e, prev_embed, history] (prev_embed: the driver's reprojection of last frame's
    accumulated embedding ē, zeros without history) with 2×2 max-pooling, bilinear upsampling
    and concatenated skips -> per pixel K sets of affinity features f_k (d channels), bandwidths
    a_k = x² and centre weights c_k = sigmoid(x), the temporal bandwidth b = x² and the
    accumulation weight λ = sigmoid(x)·history.
``kernels`` (§3.3-3.5, Eq. 3-8)
    ē = (1−λ)e + λ·prev_embed and L̄ = (1−λ)L + λ·prev_radiance (L: the pixel's linear
    radiance, ``color``); K dilated spatial filters (dilation 2^(k−1)) with weights c_k at the
    centre and exp(−a_k‖f_k(p) − f_k(q)‖²) elsewhere (Eq. 4), applied in sequence (Eq. 6); the
    last one normalised jointly with the temporal kernel exp(−b‖f_K(p) − W f_K,t−1(q)‖²) on
    the reprojected previous output (Eq. 7-8).  Taps outside the frame, and previous-frame
    taps without history, weigh 0.

State (the driver reprojects each): ``embed`` ē, ``radiance`` L̄, ``features`` f_K and
``output`` O, so the learned λ (not a fixed α) decides how much history each pixel keeps.

An ``embed`` state with an ``alpha`` (and ``history_spp``) in the spec bounds λ from above: the
driver feeds ``embed_weight`` (N, 1, 1, 1), this frame's weight by the rule of every fed state
weight (``spp / (spp + history_spp)`` for a frame of known spp, else ``alpha``;
:meth:`runtime.temporal.Protocol.alpha`), and λ = min(sigmoid(x), 1 − weight)·history for both
ē and L̄.  Not in the paper: a frame of more samples needs less history, and a learned λ that
has only seen a few hundred steps holds on to stale content at 4 spp
(docs/results/long/anf_lambda_probe.txt).  Without it the graph is the paper's.

Albedo demodulation (not in the paper): a spec whose ``[inputs].layers`` are ``["color",
"albedo"]`` (optionally with ``"emissive"``) filters the irradiance colour / (albedo + ε) instead
of the radiance, with the albedo clamped to [0, 1], lights demodulated by 1 (as WSKPN and NBG
do) and albedos below :data:`DARK_ALBEDO` blended toward 1
(:func:`training.models.common.modulation_albedo`), and re-modulates the
output; the ``radiance`` and ``output`` states then hold irradiance.  The paper's network keeps
texture through its affinity features; the CPU-sized anf-s, after a few hundred steps, did not:
on the long procedural sets it blurred every checkerboard and barely gained from 1 to 8 spp
(docs/results/anf-demod).  Without these layers the graph is the paper's.

The kernel size is the run-time setting ``kernel_size`` (§3.4, Fig. 7; an int64 scalar input,
the same for the spatial and the temporal kernels): the taps are a TorchScript loop, which the
exporter writes as an ONNX ``Loop``, so one file runs at every size without re-export (training
runs the same function eagerly: :data:`affinity_sums`).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from mcdenoise.runtime.contract import HISTORY, SAMPLES_INPUT, state_weight_name
from mcdenoise.training.models.common import (SampleEmbedding, bind_inputs, conv3, demodulate, eval_copy,
                                              modulation_albedo, remodulate)
from mcdenoise.training.models.wskpn import pad_to_multiple
from mcdenoise.training.specs import ModelSpec, SpecError, register

#: Eq. 6, 8: the normalisation's epsilon.
EPSILON = 1e-10
#: Stages, in order.
STAGES = ("embedding", "unet", "kernels")
#: Affinity exponents a·‖f(p) − f(q)‖² are bounded by this: a tap weighs at least exp(−20) ≈
#: 2e-9, which next to any weight that matters (a centre weight of 1e-3 or more) changes a sum by
#: under 1e-5 of itself, yet keeps the sums of Eq. 6 and 8 far above their ε = 1e-10 and out of
#: float32's underflow.  Unbounded, a pixel whose weights all underflow divides two rounding
#: errors (an untrained model with perturbed weights gave onnxruntime and torch outputs 3x
#: apart); bounded, such a pixel gets the mean of its taps, the same in every runtime.
AFFINITY_BOUND = 20.0
#: The pixel layers an ANF spec may read: the radiance it filters, then optionally the albedo
#: (and emissive fraction) it demodulates that radiance by (see the module docstring).
ANF_LAYERS = (("color",), ("color", "albedo"), ("color", "albedo", "emissive"))
#: A demodulating ANF blends albedos below this toward 1 (:func:`training.models.common.dark_albedo`):
#: the kernels are not trained to keep misses, mirrors and glass (albedo 0, irradiance 100x their
#: radiance) apart from their neighbours.
DARK_ALBEDO = 0.1
#: The run-time kernel-size setting's name.
KERNEL_SIZE = "kernel_size"


@dataclass(frozen=True)
class ANFParams:
    """``[params]`` of an ANF spec.

    embed_width, embed_layers: the per-sample MLP (paper: 32, 3).
    widths: the U-Net's encoder levels, then its bottleneck (paper: 64, 64, 64, 80, 96); the
      decoder mirrors the encoder.
    head: channels of the last level's first convolution (paper: 32).
    kernels: K, the number of dilated spatial kernels (paper: 3).
    features: d, the affinity features per kernel (paper: 8).
    """

    embed_width: int = 32
    embed_layers: int = 3
    widths: tuple[int, ...] = (64, 64, 64, 80, 96)
    head: int = 32
    kernels: int = 3
    features: int = 8

    def __post_init__(self):
        if self.embed_width < 1 or self.embed_layers < 1 or self.head < 1:
            raise ValueError("embed_width, embed_layers and head must be >= 1")
        if len(self.widths) < 2 or min(self.widths) < 1:
            raise ValueError(f"widths: at least one encoder level and a bottleneck, got {list(self.widths)}")
        if self.kernels < 1 or self.features < 1:
            raise ValueError(f"kernels and features must be >= 1, got {self.kernels}, {self.features}")

    @property
    def outputs(self) -> int:
        """U-Net output channels: K·(d + 2) + 2 (f_k, a_k, c_k per kernel; b, λ)."""
        return self.kernels * (self.features + 2) + 2


def state_channels(p: ANFParams) -> dict[str, int]:
    """The temporal state of an ANF model: name -> channels."""
    return {"embed": p.embed_width, "radiance": 3, "features": p.features, "output": 3}


def affinity_sums_eager(x: torch.Tensor, f: torch.Tensor, g: torch.Tensor, a: torch.Tensor,
                        mask: torch.Tensor, size: torch.Tensor, dilation: int, skip_centre: bool, bound: float):
    """Σ_q w(p, q)·x(q) and Σ_q w(p, q) over the size×size taps q = p + dilation·(i, j) of
    every pixel p, w(p, q) = exp(−min(a(p)‖f(p) − g(q)‖², bound))·mask(q), taps outside the
    frame 0 (``bound``: :data:`AFFINITY_BOUND`; TorchScript takes no module constants).

    x (N, C, H, W); f, g (N, d, H, W) affinity features (g: of the frame the taps read);
    a (N, 1, H, W) >= 0 bandwidths; mask (N, 1, H, W) in [0, 1]; size: an odd int64 scalar
    tensor; ``skip_centre`` leaves the centre tap out (the spatial kernels weigh it c).
    Returns (numerator (N, C, H, W), denominator (N, 1, H, W)), summed in tap order."""
    k = int(size)
    r = k // 2
    h, w = x.shape[2], x.shape[3]
    pad = r * dilation
    xp = F.pad(x, [pad, pad, pad, pad])
    gp = F.pad(g, [pad, pad, pad, pad])
    mp = F.pad(mask, [pad, pad, pad, pad])
    num = torch.zeros_like(x)
    den = torch.zeros_like(a)
    for i in range(k * k):
        dy = (i // k - r) * dilation
        dx = (i % k - r) * dilation
        if not (skip_centre and dy == 0 and dx == 0):
            d = f - gp[:, :, pad + dy:pad + dy + h, pad + dx:pad + dx + w]
            e = torch.clamp(a * (d * d).sum(1, keepdim=True), max=bound)
            wgt = torch.exp(-e) * mp[:, :, pad + dy:pad + dy + h, pad + dx:pad + dx + w]
            num = num + wgt * xp[:, :, pad + dy:pad + dy + h, pad + dx:pad + dx + w]
            den = den + wgt
    return num, den


#: :func:`affinity_sums_eager` as TorchScript: the form the exporter writes as an ONNX ``Loop`` (the
#: kernel size a run-time input).  Training runs the eager form of the same function: a training
#: step took 7.3 s against 9.5 s as TorchScript (docs/results/anf-demod/step_time.txt).
affinity_sums = torch.jit.script(affinity_sums_eager)


def spatial_filter(x, f, a, c, size, dilation: int, sums=affinity_sums):
    """One spatial kernel of Eq. 4 applied as Eq. 6: (N, 3, H, W) -> (N, 3, H, W); also
    returns its (numerator, denominator) for Eq. 8's joint normalisation.  ``sums``:
    :func:`affinity_sums` or its eager form."""
    ones = torch.ones_like(a)
    num, den = sums(x, f, f, a, ones, size, dilation, True, AFFINITY_BOUND)
    return num + c * x, den + c


class Embedding(SampleEmbedding):
    """Stage "embedding": samples (N, S, F, H, W) -> e (N, E, H, W), Eq. 1."""

    def __init__(self, groups: tuple[tuple[str, str], ...], p: ANFParams):
        super().__init__(groups, p.embed_width, p.embed_layers)


class UNet(nn.Module):
    """Stage "unet": [e, prev_embed, history] -> the per-pixel parameters (N, K(d+2)+2, H, W)."""

    def __init__(self, p: ANFParams):
        super().__init__()
        enc, bott = p.widths[:-1], p.widths[-1]
        self.multiple = 2 ** len(enc)
        cin = 2 * p.embed_width + 1
        self.down = nn.ModuleList()
        for w in enc:
            self.down.append(nn.Sequential(conv3(cin, w), conv3(w, w)))
            cin = w
        self.bottleneck = nn.Sequential(conv3(cin, bott), conv3(bott, bott))
        self.up = nn.ModuleList()
        cin = bott
        outs = list(enc[1:][::-1]) + [p.head]          # decoder level widths, coarse to fine
        for j, (skip, w) in enumerate(zip(enc[::-1], outs)):
            last = j == len(outs) - 1                   # its second convolution is the output
            self.up.append(nn.Sequential(conv3(cin + skip, w), conv3(w, p.outputs, act=False) if last else conv3(w, w)))
            cin = w

    def forward(self, e, prev_embed, history):
        """e, prev_embed (N, E, H, W); history (N, 1, H, W) in [0, 1] -> (N, K(d+2)+2, H, W) raw
        (activations are applied by the kernels stage). Any H, W (padded to a multiple of
        2^levels inside, cropped back)."""
        h, w = e.shape[2], e.shape[3]
        x = pad_to_multiple(torch.cat([e, prev_embed, history], dim=1), self.multiple)
        skips = []
        for level in self.down:
            x = level(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottleneck(x)
        for level, skip in zip(self.up, skips[::-1]):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = level(torch.cat([x, skip], dim=1))
        return x[:, :, :h, :w]


class Kernels(nn.Module):
    """Stage "kernels": temporal accumulation (Eq. 3, 5), K spatial kernels (Eq. 4, 6) and the
    temporal kernel (Eq. 7, 8).  In training mode it keeps the bandwidth regulariser of Eq. 13
    of its last call in :attr:`regularizer`."""

    def __init__(self, p: ANFParams):
        super().__init__()
        self.k, self.d = p.kernels, p.features
        self.regularizer = None

    def forward(self, params, e, color, prev_embed, prev_radiance, prev_features, prev_output, history, size,
                weight=None):
        """params: the U-Net's output; e (N, E, H, W); color (N, 3, H, W) linear HDR (exposed), the
        radiance or, in a demodulating spec, the irradiance;
        prev_*: the driver's reprojected state (zeros without history); history (N, 1, H, W);
        size: int64 scalar kernel size; weight: None, or (N, 1, 1, 1) in [0, 1], the current
        frame's least weight in the accumulation (λ <= 1 − weight).  Returns (output,
        next_embed, next_radiance, next_features, next_output), output (N, 3, H, W) linear HDR
        (irradiance in a demodulating spec: :meth:`ANF.forward` re-modulates it)."""
        k, d = self.k, self.d
        sums = affinity_sums_eager if self.training else affinity_sums
        lam = torch.sigmoid(params[:, -1:])
        if weight is not None:
            lam = torch.minimum(lam, 1.0 - weight)
        lam = lam * history
        b = params[:, -2:-1] ** 2
        embed = e + (prev_embed - e) * lam
        radiance = color + (prev_radiance - color) * lam
        x = radiance
        reg = b.pow(2).mean()
        for i in range(k):
            o = i * (d + 2)
            f, a, c = params[:, o:o + d], params[:, o + d:o + d + 1] ** 2, torch.sigmoid(params[:, o + d + 1:o + d + 2])
            reg = reg + a.pow(2).mean()
            num, den = spatial_filter(x, f, a, c, size, 2 ** i, sums)
            if i < k - 1:
                x = num / (den + EPSILON)
            else:
                tnum, tden = sums(prev_output, f, prev_features, b, history, size, 1, False, AFFINITY_BOUND)
                x = (num + tnum) / (den + tden + EPSILON)
                features = f
        if self.training:
            self.regularizer = reg
        return x, embed, radiance, features, x.clone()


class ANF(nn.Module):
    """The ANF model (see the module docstring); inputs and outputs as its spec implies."""

    def __init__(self, spec: ModelSpec, p: ANFParams):
        super().__init__()
        self.spec_name = spec.name
        self.params_ = p
        self.state_channels = state_channels(p)
        self.input_names = spec.input_names
        self.output_names = spec.output_names
        #: The stage whose TorchScript tap loop exports without a module scope (the exporter
        #: prefixes those nodes with it).
        self.scripted_stage = "kernels"
        #: Run-time settings and their defaults (int64 scalar inputs).
        self.settings = {st.name: st.default for st in spec.setting}
        #: (group, transfer) of the ``samples`` input's channels, in order.
        self.sample_groups = spec.inputs.sample_groups
        #: Fed state weights (graph input -> (alpha, history_spp)): the bound on λ, if any.
        self.state_weights = {state_weight_name(s.name): (s.alpha, s.history_spp) for s in spec.state if s.alpha}
        self.embedding = Embedding(spec.inputs.sample_groups, p)
        self.unet = UNet(p)
        self.kernels = Kernels(p)

    @property
    def regularizer(self):
        """Eq. 13 of the last forward in training mode (None before one)."""
        return self.kernels.regularizer

    def forward(self, *inputs):
        t = bind_inputs(self, inputs)
        e = self.embedding(t[SAMPLES_INPUT])
        params = self.unet(e, t["prev_embed"], t[HISTORY])
        color, modulation = t["color"], None
        if "albedo" in t:
            modulation = modulation_albedo(t["albedo"], t.get("emissive"), clamp=True, dark=DARK_ALBEDO)
            color = demodulate(color, modulation)
        out = self.kernels(params, e, color, t["prev_embed"], t["prev_radiance"], t["prev_features"],
                           t["prev_output"], t[HISTORY], t[KERNEL_SIZE], t.get(state_weight_name("embed")))
        if modulation is not None:
            out = (remodulate(out[0], modulation),) + tuple(out[1:])
        return out

    def deploy(self) -> "ANF":
        """The inference form: a copy in eval mode (nothing to fuse)."""
        return eval_copy(self)


@register("anf")
def build_anf(spec: ModelSpec) -> ANF:
    where = spec.path or spec.name
    p = spec.params_as(ANFParams)
    if tuple(spec.stages) != STAGES:
        raise SpecError(f"{where}: stages must be {list(STAGES)} for type 'anf', got {list(spec.stages)}")
    if tuple(spec.inputs.layers) not in ANF_LAYERS or not spec.inputs.samples:
        raise SpecError(f"{where}: type 'anf' reads [inputs].layers = one of {[list(x) for x in ANF_LAYERS]} "
                        "(the radiance it filters, and the albedo it demodulates it by) and per-sample groups "
                        "([inputs].samples)")
    if [(s.name, s.channels) for s in spec.state] != list(state_channels(p).items()):
        raise SpecError(f"{where}: [[state]] must be {list(state_channels(p).items())} for type 'anf'")
    if [s.name for s in spec.setting] != [KERNEL_SIZE] or spec.setting[0].step % 2 or spec.setting[0].min % 2 == 0:
        raise SpecError(f"{where}: type 'anf' takes one [[setting]] {KERNEL_SIZE!r} over odd sizes")
    if any(s.alpha for s in spec.state if s.name != "embed"):
        raise SpecError(f"{where}: type 'anf' takes an alpha / history_spp only on [[state]] 'embed' (the one "
                        "bound on λ, which blends ē and L̄ alike)")
    if spec.accumulate:
        raise SpecError(f"{where}: type 'anf' accumulates in its graph with the learned λ; no [[accumulate]]")
    return ANF(spec, p)

