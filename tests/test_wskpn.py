"""WSKPN model: shapes, RepVGG fusion, kernel paths (vs a brute-force Eq. 3-4), temporal
accumulation, gradients, robustness to extreme importance values."""
from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from mcdenoise.training.models import example_inputs
from mcdenoise.training.models.common import emitter_albedo, modulation_albedo
from mcdenoise.training.models.wskpn import (ALBEDO_EPS, IMPORTANCE_BOUND, LOGIT_BOUND, ImportanceNet,
                                   RepVGGBlock, ReconstructionStage,
                                   WSKPNParams, apply_kernel_boxsum, apply_kernel_unfold, bypass_mask,
                                   downsample2,
                                   fuse_kernels, fusion_factors, importance_weights, kernel_exponentials,
                                   pad_to_multiple, temporal_accumulate, upsample2)
from mcdenoise.training.specs import SpecError, build_model, list_specs, load_spec, parse_spec

WSKPN_SPECS = [n for n in list_specs() if load_spec(n).type == "wskpn"]
_ACCUMULATE = re.compile(r'\[\[accumulate\]\]\nlayer = "color"\n(?:(?:alpha|history_spp) = .*\n)+')


def _in_graph_temporal(raw: str) -> str:
    """A shipped spec (colour accumulated by the driver, [[accumulate]]) rewritten to accumulate
    in the graph instead: a leading "temporal" stage and the [[state]] accum (the option NBG uses)."""
    assert _ACCUMULATE.search(raw) and 'stages = ["prediction", "reconstruction"]' in raw
    return (_ACCUMULATE.sub('[[state]]\nname = "accum"\nchannels = 3\n', raw)
            .replace('stages = ["prediction", "reconstruction"]', 'stages = ["temporal", "prediction", "reconstruction"]'))


def _tensors(model, n, h, w, seed=0, dtype=torch.float32):
    feeds = example_inputs(model, n, h, w, seed=seed)
    return [torch.from_numpy(feeds[k]).to(dtype) for k in model.input_names]


def _randomise_bn(model, gen):
    """Non-trivial BatchNorm statistics and affine parameters (fresh ones are identities)."""
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            c = m.num_features
            m.running_mean.copy_(torch.randn(c, generator=gen) * 0.3)
            m.running_var.copy_(torch.rand(c, generator=gen) * 1.5 + 0.2)
            with torch.no_grad():
                m.weight.copy_(torch.rand(c, generator=gen) + 0.5)
                m.bias.copy_(torch.randn(c, generator=gen) * 0.2)


def _brute_force_kernel(x: np.ndarray, imp: np.ndarray, k: int) -> np.ndarray:
    """Eq. 3-4 pixel by pixel: w_p(q) = exp I(q) / sum_{q' in window(p), in image} exp I(q')."""
    _, c, h, w = x.shape
    r = k // 2
    out = np.zeros_like(x)
    for y in range(h):
        for xx in range(w):
            ys, xs = slice(max(0, y - r), min(h, y + r + 1)), slice(max(0, xx - r), min(w, xx + r + 1))
            wts = np.exp(imp[0, 0, ys, xs])
            out[0, :, y, xx] = (x[0][:, ys, xs] * wts).sum(axis=(1, 2)) / wts.sum()
    return out


# ----------------------------------------------------------------------------------------------
# shapes and interface
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", WSKPN_SPECS)
@pytest.mark.parametrize("size", [(16, 24), (13, 18)])
def test_forward_shapes_and_finite(name, size):
    torch.manual_seed(0)
    model = build_model(load_spec(name))
    outs = model(*_tensors(model, 2, *size))
    assert isinstance(outs, tuple) and len(outs) == len(model.output_names)
    assert outs[0].shape == (2, 3, *size)
    for o, n in zip(outs[1:], model.output_names[1:]):
        assert o.shape == (2, model.state_channels[n[len("next_"):]], *size)
    assert all(torch.isfinite(o).all() for o in outs)


@pytest.mark.parametrize("name", WSKPN_SPECS)
def test_forward_rejects_wrong_input_count(name):
    model = build_model(load_spec(name))
    with pytest.raises(TypeError, match="takes"):
        model(*_tensors(model, 1, 8, 8)[:-1])


@pytest.mark.parametrize("name", WSKPN_SPECS)
def test_output_is_a_convex_combination_of_demodulated_input(name):
    """Every kernel weight and fusion weight is in [0, 1] and sums to 1 (and Eq. 7 with α in
    [0, 1] keeps a constant image constant): a constant irradiance image comes back exactly."""
    torch.manual_seed(1)
    model = build_model(load_spec(name)).eval()
    t = _tensors(model, 1, 20, 28)
    names = model.input_names
    # what the model (de)modulates by: lights by 1, dark albedos blended toward 1 (dark_albedo)
    rec = model.reconstruction
    albedo = modulation_albedo(t[names.index("albedo")], t[names.index("emissive")] if "emissive" in names else None,
                               rec.albedo_clamp, rec.dark_albedo)
    t[names.index("color")] = 0.7 * (albedo + ALBEDO_EPS)  # irradiance 0.7 everywhere
    if "history" in names:
        t[names.index("history")] = torch.zeros_like(t[names.index("history")])
    with torch.no_grad():
        out = model(*t)[0]
    torch.testing.assert_close(out, 0.7 * (albedo.expand_as(out) + ALBEDO_EPS), rtol=1e-5, atol=1e-6)


def test_builder_validates_stages_state_and_layers():
    raw = _in_graph_temporal(load_spec("wskpn-3").raw)
    assert build_model(parse_spec(raw, "s.toml")).input_names[-2:] == ("prev_accum", "history")
    with pytest.raises(SpecError, match=r"stages must be \['temporal', 'prediction', 'reconstruction'\]"):
        build_model(parse_spec(raw.replace('"temporal", "prediction", "reconstruction"',
                                           '"prediction", "temporal", "reconstruction"'), "s.toml"))
    with pytest.raises(SpecError, match=r"\[\[state\]\] must be \[\('accum', 3\)\]"):
        build_model(parse_spec(raw.replace("channels = 3", "channels = 4"), "s.toml"))
    with pytest.raises(SpecError, match=r"\[inputs\]\.layers must be"):
        build_model(parse_spec(raw.replace('"color", "albedo", "normal", "depth"', '"color", "albedo", "normal"'),
                               "s.toml"))
    with pytest.raises(SpecError, match=r"\[params\]: kernel_sizes: need odd sizes"):
        build_model(parse_spec(raw.replace("kernel_sizes = [3, 5, 7, 9, 11, 13]", "kernel_sizes = [3, 4]"), "s.toml"))
    with pytest.raises(SpecError, match=r"\[params\]: widths: need 1 positive"):
        build_model(parse_spec(raw.replace("widths = [16]", "widths = [16, 8]"), "s.toml"))

    # the emissive layer is an addition a spec may make once (NBG's too), and the only one
    with pytest.raises(SpecError, match=r"duplicate entries"):
        build_model(parse_spec(raw.replace('"depth"]', '"depth", "emissive", "emissive"]'), "s.toml"))
    nbg = load_spec("nbg-2l-1g").raw
    for r in (raw, nbg):
        with pytest.raises(SpecError, match=r"optionally with \['emissive'\]"):
            build_model(parse_spec(r.replace('"depth"]', '"depth", "position"]'), "s.toml"))


def test_lights_demodulate_by_one_and_the_network_sees_them():
    """emitter_albedo: albedo where no sample hit a light, 1 where all did, the coverage mix
    between, whatever value the layer holds (clamped). A model reading the layer gives a light
    an irradiance of its colour, not colour / ALBEDO_EPS, and its ImportanceNet an 11th channel."""
    albedo = torch.tensor([0.0, 0.5, 0.8, 0.2]).reshape(1, 1, 2, 2).expand(1, 3, 2, 2)
    e = torch.tensor([1.0, 0.5, 0.0, 7.0]).reshape(1, 1, 2, 2)
    got = emitter_albedo(albedo, e)[0, 0].flatten().tolist()
    assert got == pytest.approx([1.0, 0.75, 0.8, 1.0])
    assert emitter_albedo(albedo, None) is albedo
    torch.manual_seed(0)
    plain, lit = build_model(load_spec("wskpn-6")), build_model(load_spec("wskpn-6e"))
    first = [[m for m in x.prediction.modules() if isinstance(m, torch.nn.Conv2d)][0] for x in (plain, lit)]
    assert (first[0].in_channels, first[1].in_channels) == (10, 11)
    # a light (colour 15.7, albedo 0) beside a dark wall: with the layer its demodulated value
    # is 15.7 (not 1,570), so no kernel can spread a hundredfold light into the wall
    lit.eval()
    t = _tensors(lit, 1, 16, 16)
    names = lit.input_names
    t[names.index("albedo")][:] = 0.7
    t[names.index("albedo")][..., :8] = 0.0
    t[names.index("emissive")][:] = 0.0
    t[names.index("emissive")][..., :8] = 1.0
    t[names.index("color")][:] = 0.01
    t[names.index("color")][..., :8] = 15.7
    with torch.no_grad():
        out = lit(*t)[0]
    assert float(out[..., 8:].max()) <= 15.7 * (0.7 + ALBEDO_EPS) + 1e-4     # at most the light's own value
    assert float(out[..., :8].min()) >= 0.01 * (1 + ALBEDO_EPS) - 1e-6
    # a rough conductor's albedo AOV of 58 re-modulates by 1 with albedo_clamp (wskpn-6e has it)
    assert lit.reconstruction.albedo_clamp and not plain.reconstruction.albedo_clamp
    t[names.index("albedo")][..., 8:] = 58.0
    with torch.no_grad():
        out = lit(*t)[0]
    assert float(out[..., 8:].max()) <= 15.7 * (1 + ALBEDO_EPS) + 1e-4


def _bypass_spec(raw: str | None = None) -> str:
    """wskpn-4x3-aa with the emissive layer and ``emitter_bypass`` (docs/results/emitters)."""
    raw = raw or load_spec("wskpn-4x3-aa").raw
    assert "\nconv = 3" in raw and "emitter_bypass" not in raw
    if '"emissive"]' not in raw:
        assert '"depth"]' in raw
        raw = raw.replace('"depth"]', '"depth", "emissive"]')
    return raw.replace("\nconv = 3", "\nemitter_bypass = true\nconv = 3")


@pytest.mark.parametrize("path", ["boxsum", "unfold"])
def test_emitter_bypass_keeps_lights_out_of_every_kernel(path):
    """With ``emitter_bypass`` a light 10^5 times its surroundings reaches no other pixel, whatever
    weight the network gives it, and passes through itself; a light filling whole windows (empty
    windows) stays finite in float32 and float64, training and deployed."""
    torch.manual_seed(0)
    model = build_model(parse_spec(_bypass_spec(), "s.toml"))
    model.kernel_path = path
    names = model.input_names
    t = _tensors(model, 2, 32, 32)
    light = torch.zeros(2, 1, 32, 32)
    light[..., 10:14, 10:20] = 1.0         # a small light inside the frame
    light[..., :6, :] = 1.0                # a strip wider than the 13x13 window's half: empty windows
    light[1, :, 20, 5] = 0.25              # an edge pixel at 4 spp: one sample of four hit the light
    t[names.index("emissive")][:] = light
    colour = t[names.index("color")]
    colour[:] = colour.clamp(max=1.0)
    colour[light.expand_as(colour) > 0] = 1e5
    keep = bypass_mask(light).expand_as(colour) > 0
    for dtype, mode in ((torch.float32, "eval"), (torch.float64, "train"), (torch.float32, "train")):
        m = model.to(dtype)
        m.train(mode == "train")
        with torch.no_grad():
            out = m(*[x.to(dtype) for x in t])[0]
        assert torch.isfinite(out).all(), (dtype, mode)
        assert float(out[keep].max()) < 1e3, (dtype, mode)           # no light bled in
        torch.testing.assert_close(out[~keep], colour[~keep].to(dtype), rtol=0, atol=0)
    with torch.no_grad():
        out = model.float().deploy(path)(*t)[0]
    assert torch.isfinite(out).all() and float(out[keep].max()) < 1e3
    # without the bypass the same weights let the light through (the test can fail)
    plain = build_model(parse_spec(_bypass_spec().replace("emitter_bypass = true", "emitter_bypass = false"), "s.toml"))
    plain.load_state_dict(model.state_dict())
    plain.eval()
    with torch.no_grad():
        assert float(plain(*t)[0][keep].max()) > 1e3


def test_emitter_bypass_paths_agree_and_gradients_stay_finite():
    """boxsum and unfold agree where the mask keeps a pixel (its own tap is always in); the
    float64 training form has finite gradients with empty windows."""
    gen = torch.Generator().manual_seed(3)
    x = torch.rand(2, 3, 24, 24, generator=gen, dtype=torch.float64)
    e = torch.zeros(2, 1, 24, 24, dtype=torch.float64)
    e[..., :8, :] = 1.0
    e[..., 12:15, 12:15] = 0.5
    x[e.expand_as(x) > 0] = 1e4
    keep = bypass_mask(e)
    imp = (30 * torch.randn(2, 6, 24, 24, generator=gen, dtype=torch.float64)).requires_grad_()
    logits = torch.randn(2, 6, 24, 24, generator=gen, dtype=torch.float64)
    sizes = (3, 5, 7, 9, 11, 13)
    box = fuse_kernels(x, imp, logits, sizes, "boxsum", keep)
    unf = fuse_kernels(x, imp, logits, sizes, "unfold", keep)
    k = keep.expand_as(box) > 0
    torch.testing.assert_close(box[k], unf[k], rtol=1e-9, atol=0)
    assert float(box.detach()[k].max()) <= 1.0 + 1e-9
    box.sum().backward()
    assert torch.isfinite(imp.grad).all()


def test_dark_albedo_bounds_what_a_miss_spreads_into_its_neighbours():
    """A miss (the sky: albedo 0, colour 1) beside a grey wall (albedo 0.5, colour 0.1), the
    kernels told to weigh the sky 10^4 times the wall: demodulated by the albedo itself the sky's
    irradiance is 100 and the wall's output approaches 100·0.5; with ``dark_albedo`` = 0.1 the
    sky's irradiance is its colour, and the wall's output stays below the sky's colour."""
    def wall_max(dark):
        stage = ReconstructionStage(WSKPNParams(blocks=1, widths=(4,), kernel_sizes=(3, 5), dark_albedo=dark))
        albedo = torch.full((1, 3, 8, 8), 0.5, dtype=torch.float64)
        albedo[..., :4] = 0.0
        accum = torch.full((1, 3, 8, 8), 0.1, dtype=torch.float64)
        accum[..., :4] = 1.0
        pred = torch.zeros(1, 4, 8, 8, dtype=torch.float64)
        pred[:, :2, :, :4] = 9.2       # log(10^4): every kernel weighs the sky pixels 10^4 x
        return float(stage(accum, albedo, [pred])[..., 4:].max())
    assert wall_max(0.0) > 20.0
    assert wall_max(0.1) < 1.0
    with pytest.raises(ValueError, match="dark_albedo: must be in"):
        WSKPNParams(blocks=1, widths=(4,), dark_albedo=1.5)


def test_emitter_bypass_needs_the_emissive_layer_and_one_level():
    raw = _bypass_spec()
    with pytest.raises(ValueError, match="emitter_bypass needs the 'emissive' layer"):
        build_model(parse_spec(raw.replace('"depth", "emissive"]', '"depth"]'), "s.toml"))
    with pytest.raises(ValueError, match="emitter_bypass: needs levels = 1"):
        WSKPNParams(blocks=1, widths=(4, 4), levels=2, emitter_bypass=True)


# ----------------------------------------------------------------------------------------------
# RepVGG re-parameterisation
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("size", [5, 3])
@pytest.mark.parametrize("batchnorm", [True, False])
@pytest.mark.parametrize("cin,cout,act", [(6, 6, True), (5, 7, True), (7, 4, False)])
def test_repvgg_fused_equals_multi_branch(batchnorm, cin, cout, act, size):
    """float64: fused == multi-branch to 1e-12 (the fusion is exact algebra); float32: 1e-5
    relative to the output's largest magnitude (rounding of 4 summed convolutions)."""
    gen = torch.Generator().manual_seed(cin * 10 + cout)
    block = RepVGGBlock(cin, cout, act=act, batchnorm=batchnorm, size=size)
    _randomise_bn(block, gen)
    block.eval()
    x = torch.randn(2, cin, 11, 9, generator=gen)
    with torch.no_grad():
        ref32, fused32 = block(x), block.fuse()(x)
        b64 = block.double()
        ref64, fused64 = b64(x.double()), b64.fuse()(x.double())
    assert (ref64 - fused64).abs().max() <= 1e-12 * ref64.abs().max()
    assert (ref32 - fused32).abs().max() <= 1e-5 * ref32.abs().max()
    assert fused64.shape == ref64.shape == (2, cout, 11, 9)
    assert block.fuse().conv.kernel_size == (size, size)
    if act:
        assert (ref32 >= 0).all() and (ref32 == 0).any()


def test_conv_3_blocks_have_no_5x5_branch_and_a_7x7_receptive_field():
    """``conv = 3``: every block is 3x3 + 1x1 (+ identity), so three blocks see 7x7 pixels: a
    change of one input pixel moves the importance maps within 3 pixels of it and no further
    (with ``conv = 5``: 6 pixels)."""
    for conv, reach in ((3, 3), (5, 6)):
        params = WSKPNParams(blocks=3, widths=(8,), kernel_sizes=(3, 5), conv=conv)
        net = ImportanceNet(10, params.widths[0], params.blocks, 4, batchnorm=False, conv=params.conv)
        assert all((m.branch5 is None) == (conv == 3) for m in net.modules() if isinstance(m, RepVGGBlock))
        torch.manual_seed(0)
        x = torch.rand(1, 10, 21, 21)
        y = x.clone()
        y[0, :, 10, 10] += 1.0
        with torch.no_grad():
            d = (net(y)[0] - net(x)[0]).abs().sum(dim=(0, 1))
        rows, cols = torch.nonzero(d > 0, as_tuple=True)
        assert int(rows.min()) == 10 - reach and int(rows.max()) == 10 + reach
        assert int(cols.min()) == 10 - reach and int(cols.max()) == 10 + reach


@pytest.mark.parametrize("conv", [1, 4, 7])
def test_conv_sizes_other_than_3_and_5_are_refused(conv):
    with pytest.raises(ValueError, match="conv: must be 3 or 5"):
        WSKPNParams(blocks=3, widths=(8,), conv=conv)


@pytest.mark.parametrize("name", WSKPN_SPECS)
def test_deployed_model_equals_training_form(name):
    """model.eval() vs model.deploy() (all blocks fused, non-trivial BN statistics), float64,
    so any fusion error shows above rounding: relative 1e-10."""
    torch.manual_seed(2)
    model = build_model(load_spec(name)).double()
    _randomise_bn(model, torch.Generator().manual_seed(3))
    model.eval()
    deployed = model.deploy()
    assert not any(isinstance(m, RepVGGBlock) for m in deployed.modules())
    assert any(isinstance(m, RepVGGBlock) for m in model.modules())
    t = _tensors(model, 1, 17, 22, dtype=torch.float64)
    with torch.no_grad():
        for a, b in zip(model(*t), deployed(*t)):
            assert (a - b).abs().max() <= 1e-10 * a.abs().max()


# ----------------------------------------------------------------------------------------------
# kernel application: unfold == boxsum == brute force, borders included
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [1, 3, 5, 13])
def test_kernel_paths_equal_brute_force_including_borders(k):
    """On a 9×11 image every k=13 window crosses a border; float64, tolerance 1e-12 relative."""
    gen = torch.Generator().manual_seed(k)
    x = torch.rand(1, 3, 9, 11, generator=gen, dtype=torch.float64) * 5
    imp = torch.randn(1, 1, 9, 11, generator=gen, dtype=torch.float64) * 3
    ref = torch.from_numpy(_brute_force_kernel(x.numpy(), imp.numpy(), k))
    box = apply_kernel_boxsum(x, importance_weights(imp), k)
    unf = apply_kernel_unfold(x, imp, k)
    for got in (box, unf):
        assert got.shape == x.shape
        assert (got - ref).abs().max() <= 1e-12 * ref.abs().max()


def test_fused_kernels_unfold_equals_boxsum_float32():
    """The fused six-kernel reconstruction in float32: paths agree to 1e-5 relative."""
    gen = torch.Generator().manual_seed(5)
    x = torch.rand(2, 3, 23, 31, generator=gen) * 10
    imp = torch.randn(2, 6, 23, 31, generator=gen) * 4
    logits = torch.randn(2, 6, 23, 31, generator=gen)
    sizes = (3, 5, 7, 9, 11, 13)
    box = fuse_kernels(x, imp, logits, sizes, "boxsum")
    unf = fuse_kernels(x, imp, logits, sizes, "unfold")
    assert (box - unf).abs().max() <= 1e-5 * unf.abs().max()
    with pytest.raises(ValueError, match="kernel_path"):
        fuse_kernels(x, imp, logits, sizes, "im2col")


@pytest.mark.parametrize("name", WSKPN_SPECS)
def test_model_kernel_paths_agree(name):
    torch.manual_seed(4)
    model = build_model(load_spec(name)).eval()
    t = _tensors(model, 1, 19, 26)
    with torch.no_grad():
        box = model.deploy("boxsum")(*t)[0]
        unf = model.deploy("unfold")(*t)[0]
    assert model.kernel_path == "boxsum"
    assert (box - unf).abs().max() <= 1e-5 * unf.abs().max()


def test_fusion_is_the_softmax_of_eq5():
    """Σ softmax(L)_i R_i (Eq. 5) with torch's softmax, for logits spread over ±30: the clamped
    exponentials change nothing inside the bound.  float64, 1e-12 relative."""
    gen = torch.Generator().manual_seed(8)
    x = torch.rand(1, 3, 17, 19, generator=gen, dtype=torch.float64) * 4
    imp = torch.randn(1, 3, 17, 19, generator=gen, dtype=torch.float64) * 5
    logits = (torch.rand(1, 3, 17, 19, generator=gen, dtype=torch.float64) - 0.5) * 60
    sizes = (3, 7, 13)
    soft = torch.softmax(logits, dim=1)
    want = sum(soft[:, i:i + 1] * apply_kernel_boxsum(x, importance_weights(imp[:, i:i + 1]), k)
               for i, k in enumerate(sizes))
    for path in ("boxsum", "unfold"):
        got = fuse_kernels(x, imp, logits, sizes, path)
        assert (got - want).abs().max() <= 1e-12 * want.abs().max(), path


def test_kernel_exponentials_are_weights_and_factors():
    """The stage's one-pass exponentials equal importance_weights / fusion_factors of the two
    halves, bounds included, on the prediction stage's clamped output."""
    m = 3
    pred = torch.randn(2, 2 * m, 5, 6, dtype=torch.float64) * 30
    pred[0, 0, 0, 0], pred[0, m, 0, 0] = 1e30, -1e30
    pred = pred.clamp(-LOGIT_BOUND, LOGIT_BOUND)
    weights, factors = kernel_exponentials(pred, m)
    assert len(weights) == len(factors) == m
    torch.testing.assert_close(torch.cat(weights, 1), importance_weights(pred[:, :m]), rtol=1e-15, atol=0)
    torch.testing.assert_close(torch.cat(factors, 1), fusion_factors(pred[:, m:2 * m]), rtol=0, atol=0)


def test_fusion_weights_select_a_kernel():
    """Logits strongly favouring kernel i give R_i (Eq. 5), kernel 3 ≠ kernel 13."""
    gen = torch.Generator().manual_seed(6)
    x = torch.rand(1, 3, 15, 15, generator=gen, dtype=torch.float64)
    imp = torch.randn(1, 2, 15, 15, generator=gen, dtype=torch.float64)
    for i, k in enumerate((3, 13)):
        logits = torch.full((1, 2, 15, 15), -50.0, dtype=torch.float64)
        logits[:, i] = 50.0
        got = fuse_kernels(x, imp, logits, (3, 13))
        want = apply_kernel_boxsum(x, importance_weights(imp[:, i:i + 1]), k)
        torch.testing.assert_close(got, want, rtol=1e-12, atol=0)
    assert not torch.allclose(apply_kernel_boxsum(x, importance_weights(imp[:, :1]), 3),
                              apply_kernel_boxsum(x, importance_weights(imp[:, :1]), 13))


def test_multi_resolution_combination_is_eq7():
    """α = 1: o = f − U(D(f)) + U(o_coarse); α = 0: o = f (two levels, demodulation undone)."""
    params = WSKPNParams(blocks=1, widths=(4, 4), kernel_sizes=(3, 5), levels=2)
    stage = ReconstructionStage(params)
    gen = torch.Generator().manual_seed(7)
    accum = torch.rand(1, 3, 12, 16, generator=gen, dtype=torch.float64)
    albedo = torch.rand(1, 3, 12, 16, generator=gen, dtype=torch.float64)
    fine = torch.randn(1, 5, 12, 16, generator=gen, dtype=torch.float64)
    coarse = torch.randn(1, 4, 6, 8, generator=gen, dtype=torch.float64)
    x = accum / (albedo + ALBEDO_EPS)
    f = fuse_kernels(x, fine[:, :2], fine[:, 2:4], (3, 5))
    c = fuse_kernels(downsample2(x), coarse[:, :2], coarse[:, 2:4], (3, 5))
    for blend, want in ((1e3, f - upsample2(downsample2(f)) + upsample2(c)), (-1e3, f)):
        fine[:, 4] = blend
        got = stage(accum, albedo, [fine, coarse])
        torch.testing.assert_close(got, want * (albedo + ALBEDO_EPS), rtol=1e-10, atol=1e-12)


def test_pad_to_multiple():
    x = torch.arange(2 * 5 * 7, dtype=torch.float32).view(1, 2, 5, 7)
    y = pad_to_multiple(x, 4)
    assert y.shape == (1, 2, 8, 8)
    assert torch.equal(y[..., :5, :7], x) and torch.equal(y[..., 7, :7], x[..., 4, :])
    assert pad_to_multiple(x, 1).shape == x.shape


# ----------------------------------------------------------------------------------------------
# temporal accumulation
# ----------------------------------------------------------------------------------------------

def test_temporal_accumulate_formula():
    gen = torch.Generator().manual_seed(8)
    color, prev = torch.rand(2, 1, 3, 5, 6, generator=gen)
    h = torch.rand(1, 1, 5, 6, generator=gen)
    a = 0.2
    torch.testing.assert_close(temporal_accumulate(color, prev, h, a),
                               h * (a * color + (1 - a) * prev) + (1 - h) * color)
    torch.testing.assert_close(temporal_accumulate(color, prev, torch.ones_like(h), a), a * color + (1 - a) * prev)
    huge = torch.full_like(prev, 1e30)
    assert torch.equal(temporal_accumulate(color, huge, torch.zeros_like(h), a), color)


@pytest.mark.parametrize("name", [n for n in WSKPN_SPECS if load_spec(n).accumulate])
def test_history_zero_ignores_prev_state(name):
    """The in-graph option (the shipped specs accumulate in the driver, tested in test_runtime)."""
    torch.manual_seed(9)
    model = build_model(parse_spec(_in_graph_temporal(load_spec(name).raw), f"{name}.toml")).eval()
    t = _tensors(model, 1, 16, 20)
    i_prev, i_hist = model.input_names.index("prev_accum"), model.input_names.index("history")
    color = t[model.input_names.index("color")]
    t[i_hist] = torch.zeros_like(t[i_hist])
    with torch.no_grad():
        out_a, acc_a = model(*t)
        t[i_prev] = t[i_prev] * 100 + 7
        out_b, acc_b = model(*t)
        assert torch.equal(out_a, out_b) and torch.equal(acc_a, color) and torch.equal(acc_b, color)
        t[i_hist] = torch.ones_like(t[i_hist])  # with history the state matters
        out_c, acc_c = model(*t)
    assert not torch.allclose(out_c, out_a)
    torch.testing.assert_close(acc_c, 0.2 * color + 0.8 * t[i_prev])


# ----------------------------------------------------------------------------------------------
# gradients and robustness
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("path", ["boxsum", "unfold"])
def test_gradcheck_kernel_application(path):
    gen = torch.Generator().manual_seed(10)
    x = torch.rand(1, 2, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    imp = torch.randn(1, 2, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    logits = torch.randn(1, 2, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b, c: fuse_kernels(a, b, c, (3, 5), path), (x, imp, logits))


@pytest.mark.parametrize("name", WSKPN_SPECS)
def test_gradients_reach_every_parameter(name):
    torch.manual_seed(11)
    model = build_model(load_spec(name)).train()
    t = _tensors(model, 2, 16, 16)
    outs = model(*t)
    sum(o.mean() for o in outs).backward()
    for pname, p in model.named_parameters():
        assert p.grad is not None, pname
        assert torch.isfinite(p.grad).all(), pname
    weights = [p for n, p in model.named_parameters() if n.endswith("conv.weight")]
    assert all(p.grad.abs().sum() > 0 for p in weights)


def test_huge_importance_and_logits_stay_finite_and_convex():
    x = torch.rand(1, 3, 10, 12, dtype=torch.float32) + 0.1
    imp = torch.zeros(1, 6, 10, 12)
    imp[..., ::2, :] = 1e30
    imp[..., 1::2, :] = -1e30
    imp[..., 0, 0] = float("inf")
    logits = torch.randn(1, 6, 10, 12) * 1e30
    for path in ("boxsum", "unfold"):
        out = fuse_kernels(x, imp, logits, (3, 5, 7, 9, 11, 13), path)
        assert torch.isfinite(out).all(), path
        assert (out >= x.min() * (1 - 1e-6)).all() and (out <= x.max() * (1 + 1e-6)).all(), path
    w = importance_weights(torch.tensor([[[[1e30, -1e30, 0.0]]]]))
    assert torch.equal(w, torch.exp(torch.tensor([[[[IMPORTANCE_BOUND, -IMPORTANCE_BOUND, 0.0]]]])))
    a = fusion_factors(torch.tensor([[[[1e30, -1e30, 0.0]]]]))
    assert torch.equal(a, torch.exp(torch.tensor([[[[LOGIT_BOUND, -LOGIT_BOUND, 0.0]]]])))


@pytest.mark.parametrize("name", WSKPN_SPECS)
def test_model_with_exploding_head_stays_finite(name):
    torch.manual_seed(12)
    model = build_model(load_spec(name)).eval()
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, RepVGGBlock) and not m.act:  # output blocks: importance and logits
                (m.branch5 or m.branch3).conv.weight.mul_(1e6)    # the widest branch (conv = 5 or 3)
        outs = model(*_tensors(model, 1, 16, 16))
    assert all(torch.isfinite(o).all() for o in outs)


def test_training_gradients_stay_finite_where_the_weights_span_their_whole_range():
    """Importance weights at exp(−LOGIT_BOUND) around one at exp(+LOGIT_BOUND), fusion factors at
    exp(+LOGIT_BOUND): the backward of a / boxmean(w) reaches 1e53. In float32 (the inference
    form, here in eval mode) that is inf − inf = NaN in the gradient; the training form fuses in
    float64 and gives finite gradients, and the same forward values."""
    from mcdenoise.training.models.wskpn import LOGIT_BOUND, ReconstructionStage, WSKPNParams

    params = load_spec("wskpn-6").params_as(WSKPNParams)
    m = len(params.kernel_sizes)
    g = torch.Generator().manual_seed(0)
    accum, albedo = torch.rand(1, 3, 24, 24, generator=g) * 50, torch.rand(1, 3, 24, 24, generator=g)
    pred = torch.full((1, 2 * m, 24, 24), LOGIT_BOUND)
    pred[:, :m] = -LOGIT_BOUND
    pred[:, :m, 12, 12] = LOGIT_BOUND
    upstream = torch.rand(1, 3, 24, 24, generator=g)
    out = {}
    for training in (True, False):
        p = pred.clone().requires_grad_(True)
        stage = ReconstructionStage(params).train(training)
        out[training] = stage(accum, albedo, [p])
        (out[training] * upstream).sum().backward()
        assert torch.isfinite(p.grad).all() == training
    assert out[True].dtype == torch.float32
    torch.testing.assert_close(out[True], out[False], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("k", [3, 5, 13])
def test_trainings_separable_window_mean_is_the_exported_pool(k):
    """Training's float64 fusion takes its window means as a 1×k and a k×1 pass (2k reads, not
    k²); they are the one k×k zero-padded pool the float32 export runs, to float64 rounding,
    at the borders too, on a non-square frame with values spanning the fusion's range."""
    import torch.nn.functional as F

    from mcdenoise.training.models.wskpn import _window_mean

    g = torch.Generator().manual_seed(k)
    x = torch.rand(2, 3, 21, 34, generator=g, dtype=torch.float64) * torch.exp(
        20 * torch.randn(2, 3, 21, 34, generator=g, dtype=torch.float64))
    want = F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=True)
    torch.testing.assert_close(_window_mean(x, k), want, rtol=1e-13, atol=0)
    torch.testing.assert_close(_window_mean(x.float(), k), want.float(), rtol=1e-6, atol=0)
