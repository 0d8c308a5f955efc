"""WSKPN: weight-sharing kernel prediction (Fan et al., EGSR 2021), registered as type "wskpn".

Pipeline (stages, in order; each is a submodule so exported node names carry its prefix):

``temporal`` (optional, §4.1)
    accum = history·(α·color + (1−α)·prev_accum) + (1−history)·color, α = ``params.alpha``;
    ``next_accum`` = accum.  The driver reprojects it and computes ``history``.
``prediction`` (§4.1, §5.1)
    features = [transfer(accum), albedo, (normal+1)/2, depth/max(depth)] (10 channels,
    transfer = spec ``inputs.transfer``), then the ImportanceNet: RepVGG blocks (1×1, 3×3, 5×5
    conv branches, the 5×5 left out with ``params.conv`` = 3, + identity, summed, ReLU) -> M
    importance maps I_i and M fusion logits per level.  ``levels`` > 1 makes it a U-net that predicts maps at 1/2, 1/4, ... resolution and
    one extra blend logit per finer level (§5.2).
``reconstruction`` (§3, §4.2, Eq. 3–5, 7)
    irradiance = accum / (albedo + ALBEDO_EPS); per kernel size k_i the filtered irradiance
    R_i(p) = Σ_{q∈Ω_k(p)} exp(I_i(q)) x(q) / Σ_{q∈Ω_k(p)} exp(I_i(q)); fused with softmax
    weights of the logits (Eq. 5); for levels > 1 the levels are combined from the coarsest by
    Eq. 7; finally re-modulated by (albedo + ALBEDO_EPS).  With ``params.emitter_bypass`` the
    pixels a light covers (``emissive`` > 0) are in no window and keep ``accum``.

Because a WSKPN weight depends only on the *source* pixel q, Eq. 3–4 equal
boxsum(exp(I)·x) / boxsum(exp(I)): the ``"boxsum"`` kernel path (one box filter per kernel
on a stack of w·x and w).  The ``"unfold"`` path is the paper's formulation (unfold the
importance map into k² channels, softmax over them, weighted sum of the unfolded image) kept
as the reference; both exclude taps outside the image (they get weight 0), so they agree at
the borders too.  :meth:`WSKPN.deploy` fuses the RepVGG blocks and selects ``"boxsum"``.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from mcdenoise.runtime.contract import HISTORY, state_input_name
from mcdenoise.training.models.common import (ACCUM, ALBEDO_EPS, TemporalStage, accum_interface,  # noqa: F401
                                    aux_features, bind_inputs, check_accum_model_spec, modulation_albedo,
                                    temporal_accumulate)
from mcdenoise.training.specs import ModelSpec, register

#: Fusion logits are clamped to ±LOGIT_BOUND before exp (by the prediction stage, for all its
#: outputs), so the softmax of Eq. 5 needs no per-pixel maximum (a channel reduction, slow in
#: onnxruntime).  It equals the exact softmax while every logit is within the bound: the
#: shipped models' logits stayed within ±27 on 36 two-frame windows of 12 training scenes
#: (checked when the bound was chosen).
LOGIT_BOUND = 40.0
#: Importance values share that bound, so the prediction stage's one clamp (fused into the
#: last convolution) bounds both and the weights need no clamp of their own.  A weight ratio
#: of exp(2·40) means "ignore" as surely as exp(2·20) did (the bound before, which the shipped
#: models were trained with: their quality on the bench's test sets differs by < 0.001 dB).
#: Float32 range in :func:`fuse_boxsum`: boxmean(w) >= exp(−40)·49/169 ≈ 1e-18 (a 13×13
#: window in a corner), a / boxmean(w) <= exp(80)·169/49 ≈ 2e35, and the fused sums at most
#: exp(LOGIT_BOUND)·M·max(x) ≈ 1e18·max(x): finite and never 0 for any network output.
IMPORTANCE_BOUND = LOGIT_BOUND
#: Floor of a window's weight sum with ``emitter_bypass`` (:func:`fuse_boxsum`): only an empty
#: window (every tap a light) is below it.
EMPTY_WINDOW = 1e-20
#: Kernel application variants (see module docstring); "boxsum" is the fast, deployed one.
KERNEL_PATHS = ("boxsum", "unfold")
#: Pixel layers WSKPN reads, and the channel count of the ImportanceNet input.
LAYERS = ("color", "albedo", "normal", "depth")
#: Layers a spec may add: ``emissive`` (an 11th ImportanceNet channel, and lights demodulated
#: by 1: :func:`training.models.common.emitter_albedo`).
OPTIONAL_LAYERS = ("emissive",)
N_FEATURES = 10


@dataclass(frozen=True)
class WSKPNParams:
    """``[params]`` of a "wskpn" spec.

    blocks: levels == 1: RepVGG blocks of the ImportanceNet, the last one being the linear
        output block (the paper's "3-layer" / "6-layer"); levels > 1: blocks per encoder level
        and per decoder level, plus one linear output block per level.
    widths: hidden channels, one entry per level (finest first).
    kernel_sizes: odd filter window sizes k_i fused at each level (M = len(kernel_sizes)).
    levels: resolutions (1: single-resolution WSKPN; 3: the paper's multi-resolution model).
    alpha: temporal blend factor of the current frame (used only with a "temporal" stage).
    batchnorm: BatchNorm after every RepVGG branch (as in RepVGG); folded away by deploy().
    albedo_clamp: (de)modulate by the albedo clamped to [0, 1]. Mitsuba's albedo of a rough
        conductor can be 50 or more, and a filtered irradiance re-modulated by it is a firefly
        (docs/results/scale); off by default, as the shipped models were trained.
    conv: size of the RepVGG blocks' widest branch, so of the fused convolution (5: the
        paper's 5x5, 3x3 and 1x1 branches; 3: 3x3 and 1x1 only, as RepVGG itself, 9/25 of
        the multiply-adds).
    emitter_bypass: pixels where any sample's first hit is an area light (the ``emissive``
        layer > 0, which the spec must read) are left out of every kernel and pass through
        unfiltered (the accumulated colour), so a light 100-1000x brighter than the wall
        beside it cannot bleed into it as a halo however small the kernel weight the network
        gives it (docs/results/emitters). One level only. Not in a shipped spec: under the
        history it drops the lights' antialiased edges (a pixel whose sample missed the light
        this frame is filtered from the wall alone), 0.5 dB below the emissive layer alone on
        curves-test at 1 spp.
    dark_albedo: > 0: (de)modulate by the albedo blended toward 1 below this value
        (:func:`training.models.common.dark_albedo`). Misses (the sky), mirrors and glass have
        an albedo of 0, so their irradiance is 100x their colour, and a kernel weight is per
        source pixel: the sky's own denoising weight spreads it into every object beside it
        (docs/results/emitters). 0: the albedo itself, as the paper and the shipped models.
    """

    blocks: int
    widths: tuple[int, ...]
    kernel_sizes: tuple[int, ...] = (3, 5, 7, 9, 11, 13)
    levels: int = 1
    alpha: float = 0.2
    batchnorm: bool = True
    albedo_clamp: bool = False
    conv: int = 5
    emitter_bypass: bool = False
    dark_albedo: float = 0.0

    def __post_init__(self):
        if self.levels < 1:
            raise ValueError(f"levels: must be >= 1, got {self.levels}")
        if self.blocks < 1:
            raise ValueError(f"blocks: must be >= 1, got {self.blocks}")
        if len(self.widths) != self.levels or any(w < 1 for w in self.widths):
            raise ValueError(f"widths: need {self.levels} positive channel counts (one per level), "
                             f"got {list(self.widths)}")
        if not self.kernel_sizes or any(k < 1 or k % 2 == 0 for k in self.kernel_sizes):
            raise ValueError(f"kernel_sizes: need odd sizes >= 1, got {list(self.kernel_sizes)}")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha: must be in (0, 1], got {self.alpha}")
        if self.conv not in (3, 5):
            raise ValueError(f"conv: must be 3 or 5 (the fused RepVGG convolution's size), got {self.conv}")
        if not 0.0 <= self.dark_albedo <= 1.0:
            raise ValueError(f"dark_albedo: must be in [0, 1], got {self.dark_albedo}")
        if self.emitter_bypass and self.levels != 1:
            raise ValueError(f"emitter_bypass: needs levels = 1 (the levels of Eq. 7 would mix the lights "
                             f"back in), got levels = {self.levels}")


# ----------------------------------------------------------------------------------------------
# Plain functions (each tested on its own)
# ----------------------------------------------------------------------------------------------

def wskpn_features(accum: torch.Tensor, albedo: torch.Tensor, normal: torch.Tensor,
                   depth: torch.Tensor, transfer: str, emissive: torch.Tensor | None = None) -> torch.Tensor:
    """ImportanceNet input (§5.1): :func:`training.models.common.aux_features` of the
    accumulated colour, (N, 10, H, W), (N, 11, H, W) with ``emissive``."""
    return aux_features(accum, albedo, normal, depth, transfer, emissive)


def downsample2(x: torch.Tensor) -> torch.Tensor:
    """D of Eq. 7: 2×2 average pooling, (N, C, H, W) -> (N, C, H/2, W/2); H, W even."""
    return F.avg_pool2d(x, 2)


def upsample2(x: torch.Tensor) -> torch.Tensor:
    """U of Eq. 7: nearest-neighbour 2× upsampling, (N, C, h, w) -> (N, C, 2h, 2w)."""
    return F.interpolate(x, scale_factor=2.0, mode="nearest")


def pad_to_multiple(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """Replicate-pad the bottom/right of (N, C, H, W) so H and W are multiples of ``multiple``
    (the pad amount is computed in-graph, so exports keep dynamic H, W)."""
    h, w = x.shape[-2], x.shape[-1]
    return F.pad(x, (0, (multiple - w % multiple) % multiple, 0, (multiple - h % multiple) % multiple),
                 mode="replicate")


def _window_mean(x: torch.Tensor, k: int) -> torch.Tensor:
    """Sum over the k×k window around each pixel of zero-padded ``x``, divided by k²:
    (N, C, H, W) -> same.  One k×k average pool (count_include_pad, so the divisor is k²
    everywhere: ratios of two window means are ratios of window sums).

    One pool, not a 1×k then a k×1 pass: onnxruntime's 2-D pool costs about the same for
    k = 3..13, and each pass over the (C + 1)-channel stack is a trip through memory
    (1280x720, 2 threads, the six kernels of wskpn-3: the whole frame 12 ms faster in paired
    runs); torch eager is within 15% either way.  onnxruntime pools the channels of an image
    in parallel and each channel on one thread, so a lone plane (C = 1) pools on one core;
    :func:`fuse_boxsum` pools C + 1 >= 2 channels.
    """
    if k == 1:
        return x
    if x.dtype == torch.float64:
        # Training's float64 fusion (ReconstructionStage): torch's float64 k×k pool visits k²
        # pixels per output, and its pools were 14% of a wskpn-6e step on this CPU; the 1×k and
        # k×1 passes give the same means (the zero padding makes the 2-D mean their product)
        # to float64 rounding, at 2k. The float32 path, exported, stays one pool.
        x = F.avg_pool2d(x, (1, k), stride=1, padding=(0, k // 2), count_include_pad=True)
        return F.avg_pool2d(x, (k, 1), stride=1, padding=(k // 2, 0), count_include_pad=True)
    return F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=True)


def importance_weights(importance: torch.Tensor) -> torch.Tensor:
    """exp(I) of I clamped to ±IMPORTANCE_BOUND: (N, M, H, W) -> weights in
    [exp(−bound), exp(bound)] ≈ [4e-18, 2e17].

    Every window sum is then positive and finite in float32, so Eq. 3 never divides by 0;
    a per-image maximum (the usual softmax shift) would cancel in Eq. 3 and costs a reduction.
    """
    return torch.exp(importance.clamp(-IMPORTANCE_BOUND, IMPORTANCE_BOUND))


def fusion_factors(logits: torch.Tensor) -> torch.Tensor:
    """Unnormalised softmax weights of Eq. 5: exp(L) of L clamped to ±LOGIT_BOUND,
    (N, M, H, W) -> positive factors; divided by their sum over M they are softmax(L)."""
    return torch.exp(logits.clamp(-LOGIT_BOUND, LOGIT_BOUND))


def kernel_exponentials(pred: torch.Tensor, m: int) -> tuple[list, list]:
    """:func:`importance_weights` of ``pred[:, :m]`` and :func:`fusion_factors` of
    ``pred[:, m:2m]`` as two lists of M (N, 1, H, W) planes, for ``pred`` (N, 2M, H, W) within
    ±LOGIT_BOUND (:class:`PredictionStage` clamps its output).

    One exp over all 2M channels and one split: the clamp that ends the prediction stage is
    both bounds (:data:`IMPORTANCE_BOUND` = :data:`LOGIT_BOUND`).  Slicing the two halves
    first costs onnxruntime a copy of every plane; a clamp per weight plane after the exp cost
    six more passes (1280x720: about 5 ms of the frame in paired runs).
    """
    planes = torch.exp(pred).split(1, dim=1)
    return list(planes[:m]), list(planes[m:])


def apply_kernel_boxsum(x: torch.Tensor, weights: torch.Tensor, k: int) -> torch.Tensor:
    """Eq. 3–4 with source-pixel weights: boxsum_k(w·x) / boxsum_k(w).

    x: (N, C, H, W); weights: (N, 1, H, W) positive (see :func:`importance_weights`).
    Taps outside the image contribute nothing (zero padding of both sums).
    """
    return _window_mean(weights * x, k) / _window_mean(weights, k)


def apply_kernel_unfold(x: torch.Tensor, importance: torch.Tensor, k: int,
                        keep: torch.Tensor | None = None) -> torch.Tensor:
    """Eq. 3–4 as the paper computes them (reference path): unfold the clamped importance map
    into its k² window taps, normalise them with a softmax over the taps, and take the
    weighted sum of the unfolded image.

    x: (N, C, H, W); importance: (N, 1, H, W) raw network output.  Taps outside the image are
    padded with −inf importance (weight 0) and 0 colour.  ``keep``: None, or (N, 1, H, W) in
    {0, 1}: taps where it is 0 get weight 0 too (a window with none left gives 0;
    :func:`bypass_mask`).  Memory: k²·C·H·W values.
    """
    n, c, h, w = x.shape
    r = k // 2
    i = importance.clamp(-IMPORTANCE_BOUND, IMPORTANCE_BOUND)
    taps = F.unfold(F.pad(i, (r, r, r, r), value=float("-inf")), k).view(n, k * k, h, w)
    e = torch.exp(taps - taps.amax(dim=1, keepdim=True))
    if keep is not None:
        e = e * F.unfold(keep, k, padding=r).view(n, k * k, h, w)
        wts = e / e.sum(dim=1, keepdim=True).clamp(min=torch.finfo(e.dtype).tiny)
    else:
        wts = e / e.sum(dim=1, keepdim=True)
    cols = F.unfold(x, k, padding=r).view(n, c, k * k, h, w)
    return (cols * wts.unsqueeze(1)).sum(dim=2)


def fuse_boxsum(x: torch.Tensor, weights: Sequence[torch.Tensor], factors: Sequence[torch.Tensor],
                kernel_sizes: Sequence[int], keep: torch.Tensor | None = None) -> torch.Tensor:
    """Kernel fusion (Eq. 5) on the boxsum path: Σ_i a_i R_i / Σ_i a_i with
    R_i = boxsum_k_i(w_i·x) / boxsum_k_i(w_i).

    x: (N, C, H, W) irradiance; weights (:func:`importance_weights`), factors
    (:func:`fusion_factors`): M (N, 1, H, W) positive planes each.  Returns (N, C, H, W).
    ``keep``: None, or (N, 1, H, W) in {0, 1} (:func:`bypass_mask`): the weights are
    multiplied by it, so its 0 pixels are in no window; a window with none left contributes
    0, and a pixel all of whose windows are empty gets 0 (it is its own tap where keep is 1,
    so only keep-0 pixels can).

    x carries an extra channel of ones, so one multiply and one pool per kernel give
    both sums, and the accumulated ones channel ends as Σ_i a_i: the softmax divides once.
    onnxruntime runs these (C + 1 = 4)-channel ops evenly on two threads; pooling plane by
    plane ran each vertical pass on one thread (1280x720, 2 threads: whole graph 254 -> 240 ms).
    """
    if keep is not None:
        # The ones channel becomes keep and x is masked once, so w·x1 masks both sums.
        x1 = torch.cat([x * keep, keep.to(x.dtype)], dim=1)
    else:
        x1 = torch.cat([x, torch.ones_like(x[:, :1])], dim=1)
    acc = None
    for w, a, k in zip(weights, factors, kernel_sizes):
        s = _window_mean(w * x1, k)                 # [boxmean(w·x), boxmean(w)]
        # An empty window's sums are 0: the floor makes its term 0·a/floor = 0, and it is
        # below every non-empty window's boxmean(w) >= exp(−40)/169 ≈ 2.5e-20, where a/floor
        # <= exp(40)/1e-20 stays finite in float32.
        term = s * (a / (s[:, -1:] if keep is None else s[:, -1:].clamp(min=EMPTY_WINDOW)))
        acc = term if acc is None else acc + term
    return acc[:, :-1] / (acc[:, -1:] if keep is None else acc[:, -1:].clamp(min=EMPTY_WINDOW))


def bypass_mask(emissive: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) emissive fraction -> keep mask in {0, 1} of the input's dtype: 1 where no
    sample's first hit was an area light (:attr:`WSKPNParams.emitter_bypass`)."""
    return (emissive <= 0).to(emissive.dtype)


def fuse_kernels(x: torch.Tensor, importance: torch.Tensor, logits: torch.Tensor,
                 kernel_sizes: Sequence[int], kernel_path: str = "boxsum",
                 keep: torch.Tensor | None = None) -> torch.Tensor:
    """Kernel fusion (Eq. 5): Σ_i α_i R_i with α = softmax over i of ``logits``
    (:func:`fusion_factors`, divided once at the end: onnxruntime's channel Softmax on NCHW
    is slow).  x: (N, C, H, W) irradiance; importance, logits: (N, M, H, W) with
    M = len(kernel_sizes); keep: None or (N, 1, H, W) in {0, 1}, the taps left in
    (:func:`fuse_boxsum`).  Returns (N, C, H, W).
    """
    if kernel_path not in KERNEL_PATHS:
        raise ValueError(f"kernel_path must be one of {KERNEL_PATHS}, got {kernel_path!r}")
    if kernel_path == "boxsum":
        return fuse_boxsum(x, list(importance_weights(importance).split(1, dim=1)),
                           list(fusion_factors(logits).split(1, dim=1)), kernel_sizes, keep)
    a = fusion_factors(logits)
    acc = None
    for i, k in enumerate(kernel_sizes):
        term = a[:, i:i + 1] * apply_kernel_unfold(x, importance[:, i:i + 1], k, keep)
        acc = term if acc is None else acc + term
    return acc / a.sum(dim=1, keepdim=True)


# ----------------------------------------------------------------------------------------------
# RepVGG blocks
# ----------------------------------------------------------------------------------------------

class ConvBN(nn.Module):
    """k×k convolution ('same' padding) followed by BatchNorm, or a biased convolution alone."""

    def __init__(self, cin: int, cout: int, k: int, batchnorm: bool):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, k, padding=k // 2, bias=not batchnorm)
        self.bn = nn.BatchNorm2d(cout) if batchnorm else None

    def forward(self, x):
        y = self.conv(x)
        return self.bn(y) if self.bn is not None else y

    def fused(self, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(weight (cout, cin, size, size), bias (cout,)) in float64 of conv+BN (eval-mode
        statistics), the kernel zero-padded to ``size``."""
        w = self.conv.weight.detach().double()
        p = (size - w.shape[-1]) // 2
        w = F.pad(w, (p, p, p, p))
        b = (self.conv.bias.detach().double() if self.conv.bias is not None
             else torch.zeros(w.shape[0], dtype=torch.float64, device=w.device))
        return _fold_bn(w, b, self.bn)


def _fold_bn(w: torch.Tensor, b: torch.Tensor, bn: nn.BatchNorm2d | None):
    if bn is None:
        return w, b
    scale = bn.weight.detach().double() / torch.sqrt(bn.running_var.double() + bn.eps)
    return w * scale.view(-1, 1, 1, 1), bn.bias.detach().double() + (b - bn.running_mean.double()) * scale


class FusedConv(nn.Module):
    """The inference form of a :class:`RepVGGBlock`: one ``size``×``size`` convolution (+ ReLU)."""

    def __init__(self, conv: nn.Conv2d, act: bool):
        super().__init__()
        self.conv = conv
        self.act = act

    def forward(self, x):
        y = self.conv(x)
        return F.relu(y) if self.act else y


class RepVGGBlock(nn.Module):
    """RepVGG block as WSKPN uses it (§4.1): 5×5, 3×3 and 1×1 conv branches (each with BN if
    ``batchnorm``) plus an identity branch (BN'd if ``batchnorm``) when cin == cout, summed,
    then ReLU (``act=False`` for a linear output block).  (N, cin, H, W) -> (N, cout, H, W).
    ``size=3`` leaves out the 5×5 branch (RepVGG's own block).

    :meth:`fuse` returns the equivalent single ``size``×``size`` convolution (exact up to float
    rounding; BN folded with its running statistics, i.e. the eval-mode block).
    """

    def __init__(self, cin: int, cout: int, act: bool = True, batchnorm: bool = True, size: int = 5):
        super().__init__()
        if size not in (3, 5):
            raise ValueError(f"RepVGGBlock size must be 3 or 5, got {size}")
        self.size = size
        # The 5x5 branch keeps its attribute name (and so the checkpoints' keys) where it exists.
        self.branch5 = ConvBN(cin, cout, 5, batchnorm) if size == 5 else None
        self.branch3 = ConvBN(cin, cout, 3, batchnorm)
        self.branch1 = ConvBN(cin, cout, 1, batchnorm)
        if cin == cout:
            self.identity = nn.BatchNorm2d(cout) if batchnorm else nn.Identity()
        else:
            self.identity = None
        self.act = act

    def forward(self, x):
        y = self.branch3(x) + self.branch1(x)
        if self.branch5 is not None:
            y = self.branch5(x) + y
        if self.identity is not None:
            y = y + self.identity(x)
        return F.relu(y) if self.act else y

    def fuse(self) -> FusedConv:
        k = self.size
        branches = [br for br in (self.branch5, self.branch3, self.branch1) if br is not None]
        w, b = branches[0].fused(k)
        for br in branches[1:]:
            wb, bb = br.fused(k)
            w, b = w + wb, b + bb
        if self.identity is not None:
            wi = torch.zeros_like(w)
            idx = torch.arange(w.shape[0])
            wi[idx, idx, k // 2, k // 2] = 1.0
            bn = self.identity if isinstance(self.identity, nn.BatchNorm2d) else None
            wi, bi = _fold_bn(wi, torch.zeros_like(b), bn)
            w, b = w + wi, b + bi
        first = branches[0].conv
        ref = first.weight
        conv = nn.Conv2d(first.in_channels, first.out_channels, k, padding=k // 2, bias=True,
                         dtype=ref.dtype, device=ref.device)
        with torch.no_grad():
            conv.weight.copy_(w)
            conv.bias.copy_(b)
        return FusedConv(conv, self.act)


def fuse_repvgg(module: nn.Module) -> nn.Module:
    """Replace every :class:`RepVGGBlock` inside ``module`` (in place) by its fused conv."""
    for name, child in module.named_children():
        if isinstance(child, RepVGGBlock):
            setattr(module, name, child.fuse())
        else:
            fuse_repvgg(child)
    return module


# ----------------------------------------------------------------------------------------------
# ImportanceNet
# ----------------------------------------------------------------------------------------------

class ImportanceNet(nn.Module):
    """Single-resolution ImportanceNet: ``blocks`` RepVGG blocks of size ``conv``, the last
    linear.  (N, cin, H, W) -> [(N, cout, H, W)]."""

    def __init__(self, cin: int, width: int, blocks: int, cout: int, batchnorm: bool, conv: int = 5):
        super().__init__()
        chans = [cin] + [width] * (blocks - 1) + [cout]
        self.body = nn.Sequential(*[RepVGGBlock(a, b, act=i < blocks - 1, batchnorm=batchnorm, size=conv)
                                    for i, (a, b) in enumerate(zip(chans, chans[1:]))])

    def forward(self, x):
        return [self.body(x)]


class ImportanceUNet(nn.Module):
    """Multi-resolution ImportanceNet (§5.2): a U-net with ``len(widths)`` levels.

    Encoder level l: (2×2 average pool if l > 0), ``blocks`` RepVGG blocks -> widths[l].
    Decoder level l < L−1: nearest upsample of level l+1, concatenated with the encoder skip,
    ``blocks`` RepVGG blocks -> widths[l].  Each level ends in a linear RepVGG output block of
    ``couts[l]`` channels.  (N, cin, H, W), H and W multiples of 2^(L−1) ->
    [(N, couts[l], H/2^l, W/2^l) for l in 0..L−1].
    """

    def __init__(self, cin: int, widths: Sequence[int], blocks: int, couts: Sequence[int],
                 batchnorm: bool, conv: int = 5):
        super().__init__()
        n = len(widths)

        def stack(a: int, b: int) -> nn.Sequential:
            return nn.Sequential(*[RepVGGBlock(a if j == 0 else b, b, batchnorm=batchnorm, size=conv)
                                   for j in range(blocks)])

        self.enc = nn.ModuleList([stack(cin if l == 0 else widths[l - 1], widths[l]) for l in range(n)])
        self.dec = nn.ModuleList([stack(widths[l + 1] + widths[l], widths[l]) for l in range(n - 1)])
        self.heads = nn.ModuleList([RepVGGBlock(widths[l], couts[l], act=False, batchnorm=batchnorm,
                                                size=conv) for l in range(n)])

    def forward(self, x):
        skips = []
        for l, enc in enumerate(self.enc):
            x = enc(x if l == 0 else downsample2(x))
            skips.append(x)
        outs = [self.heads[-1](x)]
        for l in reversed(range(len(self.dec))):
            x = self.dec[l](torch.cat([upsample2(x), skips[l]], dim=1))
            outs.insert(0, self.heads[l](x))
        return outs


# ----------------------------------------------------------------------------------------------
# Stages and the model
# ----------------------------------------------------------------------------------------------

class PredictionStage(nn.Module):
    """Stage "prediction": features (:func:`wskpn_features`) -> ImportanceNet.
    Returns per level (N, 2M (+1 blend logit below the coarsest level), H_l, W_l), clamped to
    ±LOGIT_BOUND."""

    def __init__(self, params: WSKPNParams, transfer: str, emissive: bool = False):
        super().__init__()
        m = len(params.kernel_sizes)
        self.transfer = transfer
        self.multiple = 2 ** (params.levels - 1)
        cin = N_FEATURES + int(emissive)
        if params.levels == 1:
            self.net = ImportanceNet(cin, params.widths[0], params.blocks, 2 * m, params.batchnorm,
                                     params.conv)
        else:
            couts = [2 * m + 1] * (params.levels - 1) + [2 * m]
            self.net = ImportanceUNet(cin, params.widths, params.blocks, couts, params.batchnorm,
                                      params.conv)

    def forward(self, accum, albedo, normal, depth, emissive=None):
        f = wskpn_features(accum, albedo, normal, depth, self.transfer, emissive)
        if self.multiple > 1:
            f = pad_to_multiple(f, self.multiple)
        preds = self.net(f)
        # Bounded here, not in reconstruction: onnxruntime fuses the clamp into the last
        # convolution (free), and the fused node keeps this stage's name for the stage table.
        return [p.clamp(-LOGIT_BOUND, LOGIT_BOUND) for p in preds]


class ReconstructionStage(nn.Module):
    """Stage "reconstruction": demodulate, filter and fuse per level, combine levels (Eq. 7),
    re-modulate.  accum, albedo: (N, 3, H, W); preds: output of :class:`PredictionStage`;
    emissive: None or (N, 1, H, W) (:func:`training.models.common.emitter_albedo`; with
    ``emitter_bypass`` its > 0 pixels also leave every kernel and pass through as ``accum``).
    Returns (N, 3, H, W) linear HDR."""

    def __init__(self, params: WSKPNParams, kernel_path: str = "boxsum"):
        super().__init__()
        if kernel_path not in KERNEL_PATHS:
            raise ValueError(f"kernel_path must be one of {KERNEL_PATHS}, got {kernel_path!r}")
        self.kernel_sizes = tuple(params.kernel_sizes)
        self.multiple = 2 ** (params.levels - 1)
        self.kernel_path = kernel_path
        self.albedo_clamp = params.albedo_clamp
        self.emitter_bypass = params.emitter_bypass
        self.dark_albedo = params.dark_albedo

    def forward(self, accum, albedo, preds, emissive=None):
        m = len(self.kernel_sizes)
        modulation = modulation_albedo(albedo, emissive, self.albedo_clamp, self.dark_albedo) + ALBEDO_EPS
        x = accum / modulation
        keep = bypass_mask(emissive) if self.emitter_bypass else None
        h, w = x.shape[-2], x.shape[-1]
        if self.multiple > 1:
            x = pad_to_multiple(x, self.multiple)
        filtered = []
        # Training runs the boxsum fusion in float64: its weights span exp(±LOGIT_BOUND), and
        # the backward of a / boxmean(w) holds a / boxmean(w)², up to 1e53, where float32 ends at
        # 3e38. The true gradient is finite (the next factor is ~boxmean(w)), but float32 gave
        # inf − inf = NaN: wskpn-6 diverged at step 2 of an 8-frame-window run. Inference and
        # the export stay float32 (forward values are bounded, see LOGIT_BOUND).
        wide = self.training and x.dtype == torch.float32 and self.kernel_path == "boxsum"
        if wide:
            x = x.double()
            keep = keep.double() if keep is not None else None
        for l, p in enumerate(preds):
            if l > 0:
                x = downsample2(x)
            if self.kernel_path == "boxsum":
                # The coarsest level has no blend channel: no slice (a copy in onnxruntime).
                p = p.double() if wide else p
                weights, factors = kernel_exponentials(p if l == len(preds) - 1 else p[:, :2 * m], m)
                f = fuse_boxsum(x, weights, factors, self.kernel_sizes, keep)
                filtered.append(f.float() if wide else f)
            else:
                filtered.append(fuse_kernels(x, p[:, :m], p[:, m:2 * m], self.kernel_sizes, "unfold", keep))
        out = filtered[-1]
        for l in reversed(range(len(preds) - 1)):
            fine = filtered[l]
            blend = torch.sigmoid(preds[l][:, 2 * m:2 * m + 1])
            # Eq. 7: fine − α·U(D(fine)) + α·U(coarse) = fine + α·U(coarse − D(fine)) (U linear)
            out = fine + blend * upsample2(out - downsample2(fine))
        if self.multiple > 1:
            out = out[:, :, :h, :w]
        out = out * modulation
        if keep is not None:
            # The lights pass through: filtered where keep is 1, the accumulated colour where 0.
            out = accum + keep.to(out.dtype) * (out - accum)
        return out


class WSKPN(nn.Module):
    """The WSKPN model; see the module docstring and ``training/models/__init__.py`` for the
    interface.  ``forward(*inputs)`` takes the tensors named by ``input_names`` in order."""

    def __init__(self, params: WSKPNParams, layers: Sequence[str], transfer: str, temporal: bool,
                 kernel_path: str = "boxsum"):
        super().__init__()
        self.params = params
        self.temporal_enabled = temporal
        if temporal:
            self.temporal = TemporalStage(params.alpha)
        if params.emitter_bypass and "emissive" not in layers:
            raise ValueError("[params] emitter_bypass needs the 'emissive' layer in [inputs] layers "
                             "(it says which pixels are lights)")
        self.prediction = PredictionStage(params, transfer, "emissive" in layers)
        self.reconstruction = ReconstructionStage(params, kernel_path)
        self.state_channels, self.input_names, self.output_names = accum_interface(layers, temporal)

    def forward(self, *inputs):
        t = bind_inputs(self, inputs)
        accum = t["color"]
        if self.temporal_enabled:
            accum = self.temporal(accum, t[state_input_name(ACCUM)], t[HISTORY])
        e = t.get("emissive")
        preds = self.prediction(accum, t["albedo"], t["normal"], t["depth"], e)
        out = self.reconstruction(accum, t["albedo"], preds, e)
        return (out, accum) if self.temporal_enabled else (out,)

    @property
    def kernel_path(self) -> str:
        return self.reconstruction.kernel_path

    @kernel_path.setter
    def kernel_path(self, value: str) -> None:
        if value not in KERNEL_PATHS:
            raise ValueError(f"kernel_path must be one of {KERNEL_PATHS}, got {value!r}")
        self.reconstruction.kernel_path = value

    def deploy(self, kernel_path: str = "boxsum") -> "WSKPN":
        """Inference copy: eval mode, RepVGG blocks fused into single convolutions, the
        given kernel path ("boxsum", the fast one, by default), no gradients.  ``self`` is
        left unchanged."""
        model = copy.deepcopy(self).eval()
        fuse_repvgg(model)
        model.kernel_path = kernel_path
        for p in model.parameters():
            p.requires_grad_(False)
        return model


@register("wskpn")
def build_wskpn(spec: ModelSpec) -> WSKPN:
    """Builder of type "wskpn": validates ``[params]`` (:class:`WSKPNParams`), the layers, the
    stages (["temporal",] "prediction", "reconstruction") and the state ([accum, 3] iff there is
    a temporal stage)."""
    params = spec.params_as(WSKPNParams)
    temporal = check_accum_model_spec(spec, "wskpn", LAYERS, ("prediction", "reconstruction"), OPTIONAL_LAYERS)
    return WSKPN(params, spec.inputs.layers, spec.inputs.transfer, temporal)
