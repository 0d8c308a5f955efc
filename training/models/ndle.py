"""NDLE: neural denoising with layer embeddings (Munkberg & Hasselgren, EGSR 2020), type "ndle".

The paper's OPTIMIZED form (§6): hierarchical kernel prediction with 5×5 kernels on three
scales instead of one 17×17 kernel.  Stages, in order, named as Table 3's rows (each a
submodule, so exported node names carry its prefix and the per-stage table reads them):

``sample_reducer`` (§3, App. B)
    each sample's features (the spec's ``[inputs].samples`` groups through their transfers;
    depth over the frame's largest sample depth) -> a per-sample MLP (``embed_layers`` 1×1
    convolutions of ``embed_width``, leaky ReLU 0.01): sample embeddings E_s, and their mean
    over the S samples.  Grows with S.
``unet`` (Fig. 3)
    a U-Net on the mean embedding (2×2 max-pooling, bilinear upsampling, concatenated skips):
    the context features C at full resolution and the decoder's features at 1/2 and 1/4 (the
    hierarchical kernel generators' context, Fig. 9).  Independent of S.
``sample_partitioner`` (Eq. 1-2, App. A lines 9-17)
    a per-sample MLP on [E_s, C] -> one weight per layer and sample, softmax over the layers,
    divided by S; the samples are splat into L layers: per layer the weighted radiance L^l,
    weight w^l, embedding E^l and occupancy n^l = Σ_s Σ_{k >= l} w^k (a sample in layer k
    passes through every layer in front of it).  Grows with S.
``layer_filtering`` (Eq. 3-5, §6 Eq. 10)
    per scale i = 0, 1, 2: the layers' L, w, n, E averaged over 2^i × 2^i blocks, a kernel
    generator MLP on [E^l, the U-Net's features at that scale] -> a 5×5 kernel per pixel and
    layer, applied as a splat (each source pixel's kernel spreads its values, App. A; computed
    as a gather of weight-times-value products shifted by the tap, so no scatter) to L, w and
    n; normalised radiance L̄/n̄ and alpha w̄/n̄ composited front to back (Eq. 5) -> G_i.
    Output: Σ_i λ_i · upsample(G_i), λ a softmax of three extra outputs of the full-scale
    generator on layer 0 (§6: "the kernel generator network of the first layer additionally
    outputs the three λ_i").  Independent of S.

Kernel weights are exp of the generator's logits bounded to ±:data:`LOGIT_BOUND` (App. A
subtracts the maximum instead: a global maximum makes every pixel depend on the whole frame and
a per-source one changes a splat's result, so a bound keeps float32 safe without either).  Every
layer's filtered radiance and alpha are ratios over its filtered occupancy, so the kernels need
no other normalisation and, unfiltered, the composite is exactly the samples' mean (energy is
conserved by construction).

The model is per frame, as in the paper (its §7 leaves the temporal domain to future work).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from mcdenoise.runtime.contract import SAMPLES_INPUT
from mcdenoise.runtime.inputs import sample_group_channels
from mcdenoise.training.models.common import LEAK, SampleEmbedding, bind_inputs, conv3, eval_copy
from mcdenoise.training.specs import ModelSpec, SpecError, register

#: Stages, in order (NDLE Table 3's rows).
STAGES = ("sample_reducer", "unet", "sample_partitioner", "layer_filtering")
#: Kernel logits are clamped to ±this before exp: a tap weighs between e^-15 ≈ 3e-7 and e^15 of
#: any other, so 25 taps × 25 sources × e^15 × radiance 1e4 stays far inside float32 and every
#: occupancy sum that is not exactly 0 stays far above :data:`EPSILON`.
LOGIT_BOUND = 15.0
#: Eq. 4's normalisation epsilon: a layer with no samples in reach has n̄ = 0, radiance and alpha 0.
EPSILON = 1e-10


def _conv1(cin: int, cout: int, bias: bool = True) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 1, bias=bias)


@dataclass(frozen=True)
class NDLEParams:
    """``[params]`` of an NDLE spec.

    embed_width, embed_layers: the sample reducer (paper: 32, 3).
    widths: the U-Net's encoder levels, then its bottleneck; the decoder mirrors the encoder and
      its full-, half- and quarter-resolution outputs are the context (paper: 128 context
      features; OPTIMIZED reduces the first encoder and last decoder convolutions to 32 / 64).
    layers: L, the layers samples are partitioned into (paper: 2; Table 2: more gain little).
    levels: scales of the hierarchical kernels (paper OPTIMIZED: 3, at 1, 1/2, 1/4).
    kernel: taps per side of each scale's kernel (paper OPTIMIZED: 5).
    partition: hidden widths of the sample partitioner (paper: 32, 16).
    generator: hidden width of the kernel generators, 3 layers (paper OPTIMIZED: 32).
    """

    embed_width: int = 32
    embed_layers: int = 3
    widths: tuple[int, ...] = (32, 64, 64, 128)
    layers: int = 2
    levels: int = 3
    kernel: int = 5
    partition: tuple[int, ...] = (32, 16)
    generator: int = 32

    def __post_init__(self):
        if self.embed_width < 1 or self.embed_layers < 1 or self.generator < 1:
            raise ValueError("embed_width, embed_layers and generator must be >= 1")
        if len(self.widths) < 2 or min(self.widths) < 1:
            raise ValueError(f"widths: at least one encoder level and a bottleneck, got {list(self.widths)}")
        if self.layers < 1:
            raise ValueError(f"layers must be >= 1, got {self.layers}")
        if not 1 <= self.levels <= len(self.widths) - 1:
            raise ValueError(f"levels must be 1..{len(self.widths) - 1} (one per U-Net decoder scale), got {self.levels}")
        if self.kernel < 1 or self.kernel % 2 == 0:
            raise ValueError(f"kernel must be odd and >= 1, got {self.kernel}")
        if not self.partition or min(self.partition) < 1:
            raise ValueError(f"partition: at least one hidden width, got {list(self.partition)}")


class SampleReducer(SampleEmbedding):
    """Stage "sample_reducer": samples (N, S, F, H, W) -> (each sample's embedding
    (N·S, E, H', W'), the mean embedding (N, E, H', W'), each sample's linear radiance
    (N·S, 3, H', W')), H' and W' padded up to the U-Net's multiple."""

    def __init__(self, groups, p: NDLEParams, radiance_offset: int, multiple: int):
        super().__init__(groups, p.embed_width, p.embed_layers)
        self.radiance_offset, self.multiple = radiance_offset, multiple

    def forward(self, samples):
        from mcdenoise.training.models.wskpn import pad_to_multiple

        n, s, f, h, w = samples.shape
        emb = self.per_sample(samples, self.multiple)
        hp, wp = emb.shape[2], emb.shape[3]
        c = self.radiance_offset
        rad = pad_to_multiple(samples[:, :, c:c + 3].reshape(n * s, 3, h, w), self.multiple)
        mean = emb.reshape(n, s, self.width, hp, wp).mean(dim=1)
        return emb, mean, rad


class UNet(nn.Module):
    """Stage "unet": the mean embedding (N, E, H, W), H and W multiples of 2^levels ->
    the decoder's outputs at scales 1, 1/2, ..., 1/2^(levels−1): a tuple, finest first, of
    (N, widths[i], H/2^i, W/2^i)."""

    def __init__(self, p: NDLEParams):
        super().__init__()
        enc, bott = p.widths[:-1], p.widths[-1]
        self.levels = p.levels
        cin = p.embed_width
        self.down = nn.ModuleList()
        for w in enc:
            self.down.append(nn.Sequential(conv3(cin, w), conv3(w, w)))
            cin = w
        self.bottleneck = nn.Sequential(conv3(cin, bott), conv3(bott, bott))
        self.up = nn.ModuleList()
        cin = bott
        for skip in enc[::-1]:
            self.up.append(nn.Sequential(conv3(cin + skip, skip), conv3(skip, skip)))
            cin = skip
        self.widths = tuple(enc)

    def forward(self, e):
        x = e
        skips = []
        for level in self.down:
            x = level(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottleneck(x)
        outs = []
        for level, skip in zip(self.up, skips[::-1]):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = level(torch.cat([x, skip], dim=1))
            outs.append(x)
        return tuple(outs[::-1][:self.levels])


class _SplitMLP(nn.Module):
    """A 1×1 MLP on [per-item features (N·M, A, H, W), per-pixel context (N, B, H, W)] where the
    context is shared by the M items of a pixel (samples or layers): its first layer is split
    into W_a·a + W_b·b so the context part runs once per pixel, not M times."""

    def __init__(self, a: int, b: int, hidden: tuple[int, ...], out: int):
        super().__init__()
        self.first_a = _conv1(a, hidden[0])
        self.first_b = _conv1(b, hidden[0], bias=False)
        mods = []
        for i in range(1, len(hidden)):
            mods += [nn.LeakyReLU(LEAK), _conv1(hidden[i - 1], hidden[i])]
        mods += [nn.LeakyReLU(LEAK), _conv1(hidden[-1], out)]
        self.rest = nn.Sequential(*mods)
        self.hidden0 = hidden[0]

    def forward(self, a, b, m: int):
        """a (N·M, A, H, W); b (N, B, H, W) -> (N·M, out, H, W)."""
        nm, _, h, w = a.shape
        x = self.first_a(a).reshape(nm // m, m, self.hidden0, h, w) + self.first_b(b).unsqueeze(1)
        return self.rest(x.reshape(nm, self.hidden0, h, w))


class SamplePartitioner(nn.Module):
    """Stage "sample_partitioner": (each sample's embedding (N·S, E, H, W) and radiance
    (N·S, 3, H, W), the context (N, C, H, W)) -> the layers (N·L, 3 + 1 + 1 + E, H, W):
    per layer its radiance Σ_s w·L, weight Σ_s w, occupancy n and embedding Σ_s w·E, with the
    sample weights w softmaxed over the layers and divided by S (Eq. 1-2)."""

    def __init__(self, p: NDLEParams, context: int):
        super().__init__()
        self.layers, self.width = p.layers, p.embed_width
        self.mlp = _SplitMLP(p.embed_width, context, tuple(p.partition), p.layers)

    def forward(self, emb, rad, context):
        ns, e, h, w = emb.shape
        n, L = context.shape[0], self.layers
        s = ns // n
        wts = torch.softmax(self.mlp(emb, context, s), dim=1) / s                  # (N·S, L, H, W)
        # Σ_s w_l·[L, E] as one batched MatMul per pixel: (N, H, W, L, S) @ (N, H, W, S, 3 + E).
        vals = torch.cat([rad, emb], dim=1).reshape(n, s, 3 + e, h, w).permute(0, 3, 4, 1, 2)
        wl = wts.reshape(n, s, L, h, w).permute(0, 3, 4, 2, 1)
        sums = torch.matmul(wl, vals).permute(0, 3, 4, 1, 2)                       # (N, L, 3 + E, H, W)
        weight = wts.reshape(n, s, L, h, w).sum(dim=1)                              # (N, L, H, W)
        # occupancy of layer l: the weight of the samples in layer l or behind it
        occupancy = torch.flip(torch.cumsum(torch.flip(weight, [1]), dim=1), [1])
        out = torch.cat([sums[:, :, :3], weight.unsqueeze(2), occupancy.unsqueeze(2), sums[:, :, 3:]], dim=2)
        return out.reshape(n * L, 5 + e, h, w)


def splat(values: torch.Tensor, logits: torch.Tensor, k: int) -> torch.Tensor:
    """Apply per-source k×k kernels as a splat: out(p) = Σ_t exp(logit_t(q))·values(q) with
    q = p − offset_t, taps from outside the frame 0.  values (B, C, H, W); logits (B, k², H, W),
    tap t = (dy + r)·k + (dx + r).  Computed as a gather of the products (App. A's note: a
    splat is a gather with the weights moved along with the values)."""
    r = k // 2
    h, w = values.shape[2], values.shape[3]
    wts = torch.exp(torch.clamp(logits, -LOGIT_BOUND, LOGIT_BOUND))
    out = torch.zeros_like(values)
    for t in range(k * k):
        dy, dx = t // k - r, t % k - r
        prod = F.pad(wts[:, t:t + 1] * values, [r, r, r, r])
        # out(y, x) += prod(y − dy, x − dx): the padded tensor is offset by r
        out = out + prod[:, :, r - dy:r - dy + h, r - dx:r - dx + w]
    return out


class LayerFiltering(nn.Module):
    """Stage "layer_filtering": (the layers (N·L, 5 + E, H, W), the U-Net's outputs, finest
    first, the model's input) -> output (N, 3, H, W) linear HDR radiance (Eq. 3-5, 10)."""

    def __init__(self, p: NDLEParams, contexts: tuple[int, ...]):
        super().__init__()
        self.layers, self.k, self.levels = p.layers, p.kernel, p.levels
        hidden = (p.generator, p.generator)
        taps = p.kernel * p.kernel
        # the full-scale generator also gives the λ_i of Eq. 10 (read from layer 0)
        self.generators = nn.ModuleList(
            _SplitMLP(p.embed_width, contexts[i], hidden, taps + (p.levels if i == 0 else 0)) for i in range(p.levels))

    def forward(self, layers, contexts: tuple[torch.Tensor, ...], samples):
        """``samples``: the model's input, for its unpadded H, W."""
        h, w = samples.shape[3], samples.shape[4]
        nl, c, hp, wp = layers.shape
        L, taps = self.layers, self.k * self.k
        n = nl // L
        out = None
        lam = None
        for i in range(self.levels):
            x = layers if i == 0 else F.avg_pool2d(layers, 2 ** i)
            logits = self.generators[i](x[:, 5:], contexts[i], L)                  # (N·L, taps (+levels), h_i, w_i)
            if i == 0 and self.levels > 1:
                lam = torch.softmax(logits.reshape(n, L, -1, hp, wp)[:, 0, taps:], dim=1)   # (N, levels, H, W)
            f = splat(x[:, :5], logits[:, :taps], self.k)                           # (N·L, 5, h_i, w_i)
            f = f.reshape(n, L, 5, f.shape[2], f.shape[3])
            occ = f[:, :, 4:5] + EPSILON
            radiance, alpha = f[:, :, :3] / occ, f[:, :, 3:4] / occ
            g = radiance[:, 0]
            through = 1.0 - alpha[:, 0]
            for j in range(1, L):                                                  # Eq. 5, front to back
                g = g + radiance[:, j] * through
                through = through * (1.0 - alpha[:, j])
            if i > 0:
                g = F.interpolate(g, scale_factor=float(2 ** i), mode="bilinear", align_corners=False)
            g = g if lam is None else g * lam[:, i:i + 1]
            out = g if out is None else out + g
        return out[:, :, :h, :w]


class NDLE(nn.Module):
    """The NDLE model (see the module docstring); inputs and outputs as its spec implies:
    ``samples`` (N, S, F, H, W) in, ``output`` (N, 3, H, W) linear HDR radiance out."""

    def __init__(self, spec: ModelSpec, p: NDLEParams, radiance_offset: int):
        super().__init__()
        self.spec_name = spec.name
        self.params_ = p
        self.state_channels: dict[str, int] = {}
        self.input_names = spec.input_names
        self.output_names = spec.output_names
        self.settings: dict[str, int] = {}
        #: (group, transfer) of the ``samples`` input's channels, in order.
        self.sample_groups = spec.inputs.sample_groups
        multiple = 2 ** (len(p.widths) - 1)
        self.sample_reducer = SampleReducer(spec.inputs.sample_groups, p, radiance_offset, multiple)
        self.unet = UNet(p)
        self.sample_partitioner = SamplePartitioner(p, self.unet.widths[0])
        self.layer_filtering = LayerFiltering(p, self.unet.widths)

    def forward(self, *inputs):
        t = bind_inputs(self, inputs)
        samples = t[SAMPLES_INPUT]
        emb, mean, rad = self.sample_reducer(samples)
        contexts = self.unet(mean)
        layers = self.sample_partitioner(emb, rad, contexts[0])
        return (self.layer_filtering(layers, contexts, samples),)

    def deploy(self) -> "NDLE":
        """The inference form: a copy in eval mode (nothing to fuse)."""
        return eval_copy(self)


@register("ndle")
def build_ndle(spec: ModelSpec) -> NDLE:
    where = spec.path or spec.name
    p = spec.params_as(NDLEParams)
    if tuple(spec.stages) != STAGES:
        raise SpecError(f"{where}: stages must be {list(STAGES)} for type 'ndle', got {list(spec.stages)}")
    groups = [g for g, _ in spec.inputs.sample_groups]
    if "radiance" not in groups:
        raise SpecError(f"{where}: type 'ndle' splats each sample's linear radiance: [inputs].samples needs "
                        f"the 'radiance' group, got {groups}")
    if spec.inputs.layers:
        raise SpecError(f"{where}: type 'ndle' reads samples only: [inputs].layers must be empty, "
                        f"got {list(spec.inputs.layers)}")
    if spec.state or spec.accumulate or spec.setting:
        raise SpecError(f"{where}: type 'ndle' is per frame (the paper's §7 leaves the temporal domain "
                        "to future work): no [[state]], [[accumulate]] or [[setting]]")
    offset = sum(sample_group_channels(g) for g in groups[:groups.index("radiance")])
    return NDLE(spec, p, offset)
