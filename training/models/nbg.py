"""NBG: neural bilateral grid denoiser (Meng et al., EGSR 2020), registered as type "nbg".

Pipeline (stages, in order; each is a submodule so exported node names carry its prefix):

``temporal`` (optional, §4.6)
    [outlier removal (§5, ``params.outlier_removal``)], demodulation
    irr = color / (albedo + ALBEDO_EPS) (§4.1 "data decomposition"), then the exponential
    moving average of the *demodulated* radiance with decay α = ``params.alpha`` (0.2):
    accum = history·(α·irr + (1−α)·prev_accum) + (1−history)·irr; ``next_accum`` = accum.
``guide`` (§4.1, §4.5, §5)
    GuideNet on [transfer(radiance), albedo, (normal+1)/2, depth/max(depth)] (10 channels,
    radiance = accum re-modulated by the albedo, or the input colour without a temporal stage,
    in which case outlier removal and demodulation happen here).  5×5 convolutions, ReLU,
    the last layer linear: ``grids`` guide images through a sigmoid (in [0, 1]) and, with more
    than one grid, ``grids`` blend logits normalised as exp(l − max) / Σ exp(l − max).
``splat`` (§4.2, Eq. 8–12)
    per scale s, the HDR irradiance and a homogeneous weight channel are splatted into a
    bilateral grid with tent (trilinear) weights at g(j) = (m/η_h, n/η_w, 255·guide_s(j)/η_d),
    rates (η_h, η_w, η_d) = ``params.rates``·2^s.
``slice`` (§4.3, Eq. 13, Eq. 15)
    trilinear read-out at the same guide by gathering the 8 corner cells of each pixel,
    renormalised by the sliced weight of non-empty cells (see :func:`slice_grid`), blended over
    the scales with the per-pixel weights, and re-modulated by (albedo + ALBEDO_EPS).

Grid layout.  A grid for an (H, W) image at rates (η_h, η_w, η_d) has
``D = floor(255/η_d) + 2`` range cells and ``(H−1)//η_h + 2`` × ``(W−1)//η_w + 2`` spatial
cells (:func:`grid_shape`): every pixel's coordinate ``(m/η_h, n/η_w, z)`` and the cell above it
on each axis lie inside.  (The paper's Eq. 8 gives ⌈h/η_h⌉ etc., one cell fewer than a tent of
unit support needs at the last pixel.)  Stored (N, C+1, D, Hg, Wg): C value channels, then the
weight sum Σ_j w_{p,j} of Eq. 10.

Inside the stages a grid is stored as rows (N·cells, C+1), cells in (y, x, d) order, channels
last. Splatting is dense block MatMuls with no scatter (:func:`splat_rows`): onnxruntime's
ScatterElements with reduction "add" (the earlier splat, a 1-D ``scatter_add``) is right but
runs on one thread; ScatterND with reduction "add" runs in parallel with lost updates where
indices repeat (onnxruntime 1.32 CPU, measured: errors of 8% at 4 threads), and torch's
exports of ``index_add`` and ``index_put_(accumulate=True)`` are a ScatterND *without*
reduction, wrong outright. Slicing gathers the 8 corner rows with ``index_select`` (ONNX
Gather of rows: 1.7x faster than per-element GatherElements; 5-D ``grid_sample`` does not
export). Both are differentiable w.r.t. the values and the guide (the tents carry the guide
gradient; their kinks sit on cell boundaries, where the trilinear weights are continuous).

Demodulation.  0 albedo (misses, delta BSDFs) is handled as in WSKPN, by the one
:data:`training.models.common.ALBEDO_EPS`: irradiance = radiance / (albedo + ALBEDO_EPS) is
finite everywhere and re-modulation multiplies by the same factor, so a constant-irradiance
image comes back exactly. A spec that adds the ``emissive`` layer demodulates lights by 1, and
``albedo_clamp`` by the albedo in [0, 1] (:func:`training.models.common.modulation_albedo`,
shared with WSKPN); the temporal stage, the guide's demodulation and the slice's re-modulation
all use that one albedo, while the GuideNet still sees the albedo layer as rendered.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Literal, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from mcdenoise.runtime.contract import HISTORY, state_input_name, state_weight_name
from mcdenoise.runtime.transfer import luminance as _luminance
from mcdenoise.training.models.common import (ACCUM, TemporalStage, accum_interface, aux_features, bind_inputs,
                                    check_accum_model_spec, demodulate, modulation_albedo, remodulate,
                                    temporal_accumulate)
from mcdenoise.training.specs import ModelSpec, SpecError, register

#: Range of the guide in grid units before division by η_d (Eq. 8: "d ... which we set to 255").
GUIDE_RANGE = 255.0
#: Pixel layers NBG reads, and the channel count of the GuideNet input.
LAYERS = ("color", "albedo", "normal", "depth")
N_FEATURES = 10
#: Layers a spec may add: ``emissive`` (an 11th GuideNet channel, and lights demodulated by 1:
#: :func:`training.models.common.emitter_albedo`), as in WSKPN.
OPTIONAL_LAYERS = ("emissive",)
#: Outlier removal (§5, after [KBS15]): a pixel whose luminance exceeds the mean of its 8
#: neighbours by more than OUTLIER_SIGMAS of their standard deviation *and* by more than
#: OUTLIER_SLACK of that mean is replaced by the neighbours' mean colour.
OUTLIER_SIGMAS = 3.0
OUTLIER_SLACK = 0.1
#: Floor of the slice denominator: where no non-empty cell is in reach (never with the splat
#: guide itself) the sliced value is 0 instead of 0/0.
SLICE_FLOOR = 1e-12
#: Floor of a cell's weight sum W in the "cell" normalisation's one division by W, far below the
#: smallest weight a pixel's tent gives a cell it reaches: the spatial factors are at least 1/η
#: each, the range factor at least 2^-23 or, in the lowest range cell, the guide·255/η_d itself
#: (above 1e-30 for any guide above 1e-25, a sigmoid logit above -57). So W / max(W, CELL_FLOOR)
#: is exactly 1 in every occupied cell and 0 in an empty one.
CELL_FLOOR = 1e-30
#: Slice normalisations (see :func:`slice_grid`).
NORMALIZATIONS = ("cell", "homogeneous")


@dataclass(frozen=True)
class NBGParams:
    """``[params]`` of an "nbg" spec.

    layers: convolution layers of the GuideNet (Fig. 2: 2 for 1 spp, 7 for 64 spp), all 5×5.
    width: channels of the hidden layers (the first layer's with ``dense``).
    dense: with ``dense``, layers 2..layers−1 form a dense block (each sees the concatenation
        of all earlier feature maps and adds ``growth`` channels); Fig. 2 right.
    growth: channels each dense-block layer adds (used only with ``dense``).
    grids: bilateral grid scales (1, or 3 as in §4.5; scale s halves the resolution of s−1).
    rates: (η_h, η_w, η_d) at scale 0 (§5: 4, 4, 4): pixels per cell vertically and
        horizontally, and guide units (of the range 255) per range cell; doubled per scale.
    outlier_removal: §5 pre-process of the colour (off by default; the paper used it on its
        64-spp Tungsten data).
    alpha: weight of the current frame in the temporal accumulation (used only with a
        "temporal" stage).  §4.6's "decay factor ... 0.2" is read as in BMFR [KIM*19] / SVGF,
        whose reprojection it cites, and as WSKPN's α: the new frame gets 0.2, history 0.8.
    normalization: "cell" (the paper, Eq. 10 + 13: each non-empty cell holds the weighted mean
        of its pixels and slicing averages non-empty cells) or "homogeneous" (classic bilateral
        grid: slice the weighted sums and divide by the sliced weight sum).
    albedo_clamp: (de)modulate by the albedo clamped to [0, 1]
        (:func:`training.models.common.modulation_albedo`; off, as the shipped models trained).
    """

    layers: int = 2
    width: int = 16
    dense: bool = False
    growth: int = 8
    grids: int = 3
    rates: tuple[int, ...] = (4, 4, 4)
    outlier_removal: bool = False
    alpha: float = 0.2
    normalization: Literal["cell", "homogeneous"] = "cell"
    albedo_clamp: bool = False

    def __post_init__(self):
        if self.layers < 2:
            raise ValueError(f"layers: the GuideNet needs >= 2 layers, got {self.layers}")
        if self.dense and self.layers < 3:
            raise ValueError(f"layers: a dense GuideNet needs >= 3 layers, got {self.layers}")
        if self.width < 1 or self.growth < 1:
            raise ValueError(f"width, growth: must be >= 1, got {self.width}, {self.growth}")
        if not 1 <= self.grids <= 4:
            raise ValueError(f"grids: must be 1..4 (the paper: 1 or 3), got {self.grids}")
        if len(self.rates) != 3 or any(r < 1 for r in self.rates):
            raise ValueError(f"rates: need [eta_h, eta_w, eta_d] >= 1, got {list(self.rates)}")
        if self.rates[2] * 2 ** (self.grids - 1) > GUIDE_RANGE:
            raise ValueError(f"rates: eta_d·2^(grids-1) = {self.rates[2] * 2 ** (self.grids - 1)} leaves "
                             f"no range resolution (> {GUIDE_RANGE:g})")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha: must be in (0, 1], got {self.alpha}")

    def scale_rates(self, s: int) -> tuple[int, int, int]:
        """(η_h, η_w, η_d) of scale s: ``rates``·2^s (§4.5)."""
        return tuple(r * 2 ** s for r in self.rates)


# ----------------------------------------------------------------------------------------------
# Plain functions (each tested on its own)
# ----------------------------------------------------------------------------------------------

def grid_shape(h, w, rates: Sequence[int]):
    """(D, Hg, Wg) of the grid for an (h, w) image at rates (η_h, η_w, η_d); see the module
    docstring.  h, w may be traced sizes (the export keeps them dynamic)."""
    sh, sw, sd = rates
    return int(GUIDE_RANGE // sd) + 2, (h - 1) // sh + 2, (w - 1) // sw + 2


def corners(guide: torch.Tensor, rates: Sequence[int]):
    """Trilinear corners of every pixel in the grid of :func:`grid_shape`, per corner.

    guide: (N, 1, H, W) in [0, 1] (values outside are clamped to the grid's range cells).
    The batch's grids are stored as rows (N·cells, C+1), cells = Hg·Wg·D in (y, x, d) order:
    cell p = (y·Wg + x)·D + d of image n is row n·cells + p.  Returns (base, offsets, weights,
    cells): base (N, 1, H, W) int64, the row of each pixel's lowest corner; offsets: 8 row
    offsets (ints, traced for dynamic sizes) of the corners (dz, dy, dx) in {0, 1}³; weights:
    8 tensors (N, 1, H, W), the tent weights T(g(j) − p) (Eq. 9, 11) in the guide's dtype,
    summing to 1 per pixel.  Differentiable w.r.t. ``guide`` through the range weights.
    """
    n, _, h, w = guide.shape
    sh, sw, sd = rates
    d, hg, wg = grid_shape(h, w, rates)
    cells = d * hg * wg
    dev, dt = guide.device, guide.dtype
    ys = torch.arange(h, device=dev)
    xs = torch.arange(w, device=dev)
    y0 = (ys // sh).view(h, 1)
    x0 = (xs // sw).view(1, w)
    fy = ((ys % sh).to(dt) / sh).view(h, 1)
    fx = ((xs % sw).to(dt) / sw).view(1, w)
    z = guide * (GUIDE_RANGE / sd)
    z0 = torch.floor(z).clamp(0.0, d - 2.0).detach()
    fz = z - z0
    image = (torch.arange(n, device=dev) * cells).view(n, 1, 1, 1)
    base = (y0 * wg + x0) * d + z0.to(torch.int64) + image
    offsets, weights = [], []
    for dz, wz in ((0, 1.0 - fz), (1, fz)):
        for dy, wy in ((0, 1.0 - fy), (wg * d, fy)):
            wzy = wz * wy
            for dx, wx in ((0, 1.0 - fx), (d, fx)):
                offsets.append(dz + dy + dx)
                weights.append(wzy * wx)
    return base, offsets, weights, cells


def corner_coords(guide: torch.Tensor, rates: Sequence[int]):
    """:func:`corners` gathered for slicing: (index, weight, cells) with index (N·8·H·W,)
    int64 grid rows ordered (image, corner, pixel) and weight (N, 8, H·W, 1)."""
    n, _, h, w = guide.shape
    base, offsets, weights, cells = corners(guide, rates)
    index = torch.cat([base + o for o in offsets], dim=1).reshape(-1)
    return index, torch.cat(weights, dim=1).reshape(n, 8, h * w, 1), cells


def splat_rows(values: torch.Tensor, guide: torch.Tensor, rates: Sequence[int]) -> torch.Tensor:
    """Splat (Eq. 10) of values (N, C, H, W) at guide (N, 1, H, W) in [0, 1]: the grid as rows
    (N·cells, C+1) in the order of :func:`corners`, Σ_j w_{p,j} r(j) per channel, then
    Σ_j w_{p,j}.

    Dense and scatter-free, because the spatial tents are the same for every image: the image
    is cut into blocks of η_h × η_w pixels (zero-padded, so padding carries no weight), and a
    block's K = η_h·η_w pixels reach only the 2 × 2 cells at its corner.  Per block one batched
    MatMul per spatial corner, T (D, K) @ (s_corner · v) (K, C+1), with T the range tents
    max(0, 1 − |z_k − d|) of every pixel k at every range cell d, gives that corner's cells;
    the four are padded into place and summed.  That is D·H·W·4·(C+1) FMAs (the scatter did
    8·(C+1) adds per pixel), but onnxruntime runs a MatMul on every thread, where its
    ScatterElements with a reduction runs on one (1.95 s against 0.50 s for the three grids of
    nbg-2l-3g at 1280x720, two threads).  Memory: T is H·W·D floats per scale (240 MB at 720p
    for D = 65), about the int64 indices and products the scatter held (350 MB).  The guide
    is clamped to the grid's range cells, where the tents equal :func:`corners`' weights."""
    n, c, h, w = values.shape
    sh, sw, sd = rates
    d, hg, wg = grid_shape(h, w, rates)
    hb, wb, k, c1 = hg - 1, wg - 1, sh * sw, c + 1
    dev, dt = values.device, values.dtype
    pad = (0, wb * sw - w, 0, hb * sh - h)
    v = F.pad(torch.cat([values, torch.ones_like(values[:, :1])], dim=1), pad)
    z = (F.pad(guide, pad) * (GUIDE_RANGE / sd)).clamp(0.0, d - 1.0)
    z = z.reshape(n, hb, sh, wb, sw).permute(0, 1, 3, 2, 4).reshape(n * hb * wb, 1, k)
    cell_d = torch.arange(d, device=dev, dtype=dt).view(d, 1)
    tents = torch.relu(1.0 - (z - cell_d).abs())  # (B, D, K)
    v = v.reshape(n, c1, hb, sh, wb, sw).permute(0, 2, 4, 3, 5, 1).reshape(n * hb * wb, k, c1)
    fy = torch.arange(sh, device=dev, dtype=dt) / sh
    fx = torch.arange(sw, device=dev, dtype=dt) / sw
    grid = None
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            s = (wy.view(sh, 1) * wx.view(1, sw)).reshape(1, k, 1)
            part = torch.matmul(tents, v * s).reshape(n, hb, wb, d * c1)
            part = F.pad(part, (0, 0, dx, 1 - dx, dy, 1 - dy))
            grid = part if grid is None else grid + part
    return grid.reshape(n * hg * wg * d, c1)


def splat(values: torch.Tensor, guide: torch.Tensor, rates: Sequence[int]) -> torch.Tensor:
    """Bilateral grid construction (Eq. 10–12) with tent weights.

    values: (N, C, H, W) HDR data (irradiance); guide: (N, 1, H, W) in [0, 1];
    rates: (η_h, η_w, η_d).  Returns (N, C+1, D, Hg, Wg) (see :func:`grid_shape`): weighted
    sums of each channel, then the weight sum.  Differentiable w.r.t. values and guide.
    """
    n, c = values.shape[0], values.shape[1]
    d, hg, wg = grid_shape(values.shape[-2], values.shape[-1], rates)
    grid = splat_rows(values, guide, rates)
    return grid.reshape(n, hg, wg, d, c + 1).permute(0, 4, 3, 1, 2)


def slice_rows(grid: torch.Tensor, index: torch.Tensor, weight: torch.Tensor, n, h, w,
               normalization: str = "cell") -> torch.Tensor:
    """Slicing (Eq. 13) of a row grid (N·cells, C+1) from :func:`splat_rows` at the corners
    of :func:`corner_coords` (the slicing guide's).

    With S the weighted sums and W the weight sum of a cell, "cell" reads M = S/W of the
    non-empty cells (W > 0), Eq. 10, and divides by the sliced indicator Σ_p w_p [W_p > 0],
    Eq. 13; "homogeneous" returns Σ_p w_p S_p / Σ_p w_p W_p.  Empty cells contribute to
    neither sum; where the denominator is 0 the result is 0.  Returns (N, C, h, w).
    """
    if normalization not in NORMALIZATIONS:
        raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {normalization!r}")
    c = grid.shape[1] - 1
    if normalization == "cell":
        # One division of every row by its W gives both: an empty cell holds S = 0 and W = 0, so
        # S / max(W, floor) is M there and 0 where empty, and W / max(W, floor) is the indicator
        # [W > 0] (see CELL_FLOOR), without a mask, a cast and a concatenation over all the
        # grid's rows (3.8 M at 720p), which onnxruntime's CPU kernels run slowly.
        grid = grid / grid[:, c:].clamp(min=CELL_FLOOR)
    # ONNX Gather of rows, then channels first: the corner weights then broadcast over a
    # contiguous H·W span (onnxruntime multiplies a trailing size-1 axis 4 floats per call, and
    # this order also ends without a transpose). With the division above, the slice stage takes
    # 0.62-0.64x its earlier time in onnxruntime at 720p, torch eager's whole graph within ±7%
    # (docs/results/nbg-splat: slice.sh, slice_torch.py).
    taps = grid.index_select(0, index).reshape(n, 8, -1, c + 1).transpose(2, 3)
    acc = (taps * weight.reshape(n, 8, 1, -1)).sum(dim=1)  # (N, C+1, H·W)
    out = acc[:, :c] / acc[:, c:].clamp(min=SLICE_FLOOR)
    return out.reshape(n, c, h, w)


def slice_grid(grid: torch.Tensor, guide: torch.Tensor, rates: Sequence[int],
               normalization: str = "cell") -> torch.Tensor:
    """Read a grid (N, C+1, D, Hg, Wg) from :func:`splat` at ``guide`` (N, 1, H, W) with
    trilinear weights (gather-based, :func:`slice_rows`).  Returns (N, C, H, W)."""
    n, c1 = grid.shape[0], grid.shape[1]
    index, weight, _ = corner_coords(guide, rates)
    rows = grid.permute(0, 3, 4, 2, 1).reshape(-1, c1)
    return slice_rows(rows, index, weight, n, guide.shape[-2], guide.shape[-1], normalization)


def luminance(color: torch.Tensor) -> torch.Tensor:
    """Rec. 709 luminance: (N, 3, H, W) -> (N, 1, H, W) (:func:`runtime.transfer.luminance`)."""
    return _luminance(color, 1)


def remove_outliers(color: torch.Tensor, sigmas: float = OUTLIER_SIGMAS, slack: float = OUTLIER_SLACK) -> torch.Tensor:
    """Outlier (firefly) suppression (§5, after [KBS15]).

    color: (N, 3, H, W) linear HDR, H, W >= 2.  With μ, σ² the mean and variance of the
    luminance of the 8 neighbours (reflect-padded borders, so the pixel itself never counts),
    a pixel whose luminance L exceeds (1 + slack)·μ + sigmas·σ is replaced by its neighbours'
    mean colour (written without a square root: e = L − (1+slack)·μ > 0 and e² > sigmas²·σ²).
    Smooth images are left unchanged (L ≈ μ); an isolated spike is removed.  The paper cites
    [KBS15] without giving its rule; this is that kind of local-statistics spike test.
    """
    lum = luminance(color)
    stack = torch.cat([color, lum, lum * lum], dim=1)
    mean9 = F.avg_pool2d(F.pad(stack, (1, 1, 1, 1), mode="reflect"), 3, stride=1)
    mean8 = (9.0 * mean9 - stack) / 8.0
    mu, var = mean8[:, 3:4], (mean8[:, 4:5] - mean8[:, 3:4] ** 2).clamp(min=0.0)
    excess = lum - (1.0 + slack) * mu
    outlier = ((excess > 0) & (excess * excess > (sigmas * sigmas) * var)).to(color.dtype)
    return color + outlier * (mean8[:, :3] - color)


def blend_weights(logits: torch.Tensor) -> list[torch.Tensor]:
    """Per-pixel scale weights (Eq. 15) from G logits (N, G, H, W): w_i = exp(l_i − m) / Σ,
    m = max_i l_i, written per channel (onnxruntime's channel softmax is slow), and the last
    w_{G−1} = 1 − Σ_{i<G−1} w_i as in the paper.  Returns G tensors (N, 1, H, W) in [0, 1]
    summing to 1."""
    g = logits.shape[1]
    ls = [logits[:, i:i + 1] for i in range(g)]
    m = ls[0]
    for l in ls[1:]:
        m = torch.maximum(m, l)
    m = m.detach()
    es = [torch.exp(l - m) for l in ls]
    total = es[0]
    for e in es[1:]:
        total = total + e
    ws = [e / total for e in es[:-1]]
    last = 1.0 - ws[0]
    for wi in ws[1:]:
        last = last - wi
    return ws + [last]


# ----------------------------------------------------------------------------------------------
# GuideNet and stages
# ----------------------------------------------------------------------------------------------

class GuideNet(nn.Module):
    """Fig. 2: 5×5 convolutions with ReLU, the last one linear (the stage applies the sigmoid
    to the guide channels).  Plain: ``layers``−1 hidden layers of ``width``.  Dense: one layer
    of ``width``, a dense block of ``layers``−2 layers adding ``growth`` channels each, the
    output layer on the concatenation.  (N, cin, H, W) -> (N, cout, H, W)."""

    def __init__(self, cin: int, cout: int, layers: int, width: int, dense: bool, growth: int):
        super().__init__()
        self.dense = dense
        self.first = nn.Conv2d(cin, width, 5, padding=2)
        chans = width
        hidden = []
        for _ in range(layers - 2):
            out = growth if dense else width
            hidden.append(nn.Conv2d(chans, out, 5, padding=2))
            chans = chans + out if dense else out
        self.hidden = nn.ModuleList(hidden)
        self.last = nn.Conv2d(chans, cout, 5, padding=2)

    def forward(self, x):
        x = F.relu(self.first(x))
        for conv in self.hidden:
            y = F.relu(conv(x))
            x = torch.cat([x, y], dim=1) if self.dense else y
        return self.last(x)


class NBGTemporalStage(TemporalStage):
    """Stage "temporal": [outlier removal], demodulation, then :func:`temporal_accumulate`
    of the irradiance (the shared :class:`~training.models.common.TemporalStage`)."""

    def __init__(self, alpha: float, outlier_removal: bool, albedo_clamp: bool = False):
        super().__init__(alpha)
        self.outlier_removal = outlier_removal
        self.albedo_clamp = albedo_clamp

    def forward(self, color, albedo, emissive, prev, history, weight=None):
        """``weight``: (N, 1, 1, 1) current-frame weights fed by the driver (a [[state]] with an
        alpha), else the fixed α. Returns (accumulated irradiance, the albedo it is
        (de)modulated by: :func:`modulation_albedo`, computed here so its ops belong to a stage)."""
        m = modulation_albedo(albedo, emissive, self.albedo_clamp)
        if self.outlier_removal:
            color = remove_outliers(color)
        irr = demodulate(color, m)
        acc = super().forward(irr, prev, history) if weight is None else temporal_accumulate(irr, prev, history, weight)
        return acc, m


class GuideStage(nn.Module):
    """Stage "guide": features -> GuideNet -> guides (sigmoid) and blend weights.

    ``forward(x, albedo, normal, depth, emissive=None, modulation=None)``: x is the accumulated
    irradiance when a temporal stage ran before (``demodulated=True``), else the colour, cleaned
    and demodulated here; ``modulation`` (N, 3, H, W) is the albedo it is (de)modulated by, from
    the temporal stage (default: :func:`modulation_albedo` of ``albedo``, computed here),
    ``emissive`` (N, 1, H, W) the GuideNet's 11th channel.
    Returns (irradiance (N, 3, H, W), [guide_s (N, 1, H, W)], [w_s (N, 1, H, W)], modulation)."""

    def __init__(self, params: NBGParams, transfer: str, demodulated: bool, emissive: bool = False):
        super().__init__()
        self.grids = params.grids
        self.transfer = transfer
        self.demodulated = demodulated
        self.outlier_removal = params.outlier_removal
        self.albedo_clamp = params.albedo_clamp
        cout = params.grids + (params.grids if params.grids > 1 else 0)
        self.net = GuideNet(N_FEATURES + int(emissive), cout, params.layers, params.width, params.dense, params.growth)

    def forward(self, x, albedo, normal, depth, emissive=None, modulation=None):
        m = modulation_albedo(albedo, emissive, self.albedo_clamp) if modulation is None else modulation
        if self.demodulated:
            irr, radiance = x, remodulate(x, m)
        else:
            radiance = remove_outliers(x) if self.outlier_removal else x
            irr = demodulate(radiance, m)
        raw = self.net(aux_features(radiance, albedo, normal, depth, self.transfer, emissive))
        g = self.grids
        guides = [torch.sigmoid(raw[:, i:i + 1]) for i in range(g)]
        weights = blend_weights(raw[:, g:]) if g > 1 else []
        return irr, guides, weights, m


class SplatStage(nn.Module):
    """Stage "splat": per scale, the corners of every pixel at its guide and the grid.
    Returns ([grid_s as rows (N·cells_s, 4)], [(index_s, weight_s)])."""

    def __init__(self, params: NBGParams):
        super().__init__()
        self.rates = [params.scale_rates(s) for s in range(params.grids)]

    def forward(self, irr, guides):
        grids, coords = [], []
        for rates, guide in zip(self.rates, guides):
            grids.append(splat_rows(irr, guide, rates))
            index, weight, _ = corner_coords(guide, rates)
            coords.append((index, weight))
        return grids, coords


class SliceStage(nn.Module):
    """Stage "slice": slice every scale at its guide, blend with the weights (Eq. 15) and
    re-modulate.  Returns (N, 3, H, W) linear HDR."""

    def __init__(self, params: NBGParams):
        super().__init__()
        self.normalization = params.normalization

    def forward(self, grids, coords, weights, albedo):
        n, h, w = albedo.shape[0], albedo.shape[-2], albedo.shape[-1]
        out = None
        for s, (grid, (index, weight)) in enumerate(zip(grids, coords)):
            r = slice_rows(grid, index, weight, n, h, w, self.normalization)
            if weights:
                r = r * weights[s]
            out = r if out is None else out + r
        return remodulate(out, albedo)


class NBG(nn.Module):
    """The NBG model; see the module docstring and ``training/models/__init__.py`` for the
    interface.  ``forward(*inputs)`` takes the tensors named by ``input_names`` in order."""

    def __init__(self, params: NBGParams, layers: Sequence[str], transfer: str, temporal: bool,
                 weight: tuple[float, float] | None = None):
        super().__init__()
        self.params = params
        self.temporal_enabled = temporal
        if temporal:
            self.temporal = NBGTemporalStage(params.alpha, params.outlier_removal, params.albedo_clamp)
        self.guide = GuideStage(params, transfer, demodulated=temporal, emissive="emissive" in layers)
        self.splat = SplatStage(params)
        self.slice = SliceStage(params)
        self.state_channels, self.input_names, self.output_names = accum_interface(layers, temporal)
        # [[state]] accum with an alpha: the driver feeds this frame's weight (spp-aware)
        self.state_weights = {state_weight_name(ACCUM): weight} if temporal and weight else {}
        self.input_names += tuple(self.state_weights)

    def forward(self, *inputs):
        t = bind_inputs(self, inputs)
        x, e, m = t["color"], t.get("emissive"), None
        if self.temporal_enabled:
            x, m = self.temporal(x, t["albedo"], e, t[state_input_name(ACCUM)], t[HISTORY],
                                 t.get(state_weight_name(ACCUM)))
        irr, guides, weights, m = self.guide(x, t["albedo"], t["normal"], t["depth"], e, m)
        grids, coords = self.splat(irr, guides)
        out = self.slice(grids, coords, weights, m)
        return (out, irr) if self.temporal_enabled else (out,)

    def deploy(self) -> "NBG":
        """Inference copy: eval mode, no gradients (there is nothing to fuse).  ``self`` is
        left unchanged."""
        model = copy.deepcopy(self).eval()
        for p in model.parameters():
            p.requires_grad_(False)
        return model


@register("nbg")
def build_nbg(spec: ModelSpec) -> NBG:
    """Builder of type "nbg": validates ``[params]`` (:class:`NBGParams`), the layers, the
    stages (["temporal",] "guide", "splat", "slice") and the state ([accum, 3] iff there is a
    temporal stage)."""
    params = spec.params_as(NBGParams)
    temporal = check_accum_model_spec(spec, "nbg", LAYERS, ("guide", "splat", "slice"), OPTIONAL_LAYERS)
    state = spec.state[0] if spec.state else None
    if state is not None and state.alpha and state.alpha != params.alpha:
        raise SpecError(f"{spec.path or spec.name}: [[state]] accum alpha {state.alpha} differs from "
                        f"[params].alpha {params.alpha}: one weight, in both places")
    weight = (state.alpha, state.history_spp) if state is not None and state.alpha else None
    return NBG(params, spec.inputs.layers, spec.inputs.transfer, temporal, weight)
