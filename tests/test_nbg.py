"""NBG model: splat and slice against brute force (torch and onnxruntime), gradients, outlier
removal, blend weights, interface, temporal state and a short training run."""
from __future__ import annotations

import itertools

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from mcdenoise.training.models import example_inputs
from mcdenoise.training.models.common import ALBEDO_EPS, demodulate, modulation_albedo, temporal_accumulate
from mcdenoise.training.models.nbg import (GUIDE_RANGE, NORMALIZATIONS, NBGParams, blend_weights, corner_coords, grid_shape,
                                 remove_outliers, slice_grid, splat)
from mcdenoise.training.specs import SpecError, build_model, list_specs, load_spec, parse_spec

NBG_SPECS = [n for n in list_specs() if load_spec(n).type == "nbg"]


def _tent(x: float) -> float:
    return max(1.0 - abs(x), 0.0)


def _brute_force_splat(values: np.ndarray, guide: np.ndarray, rates) -> np.ndarray:
    """Eq. 10-12 pixel by pixel and cell by cell: (N, C+1, D, Hg, Wg) weighted sums and the
    weight sum, with T(g(j) - p) the tent of Eq. 9 at g(j) = (m/eta_h, n/eta_w, 255 g/eta_d)."""
    n, c, h, w = values.shape
    sh, sw, sd = rates
    d, hg, wg = grid_shape(h, w, rates)
    out = np.zeros((n, c + 1, d, hg, wg))
    for b, m, k in itertools.product(range(n), range(h), range(w)):
        gz = GUIDE_RANGE * guide[b, 0, m, k] / sd
        v = np.append(values[b, :, m, k], 1.0)
        for z, y, x in itertools.product(range(d), range(hg), range(wg)):
            t = _tent(m / sh - y) * _tent(k / sw - x) * _tent(gz - z)
            if t:
                out[b, :, z, y, x] += t * v
    return out


def _splat_case(seed=0, n=2, h=7, w=9):
    """Small input with many pixels per cell (repeated indices) and guides at 0, 1 and on
    range-cell boundaries besides random ones."""
    rng = np.random.default_rng(seed)
    values = rng.exponential(1.0, (n, 3, h, w))
    guide = rng.random((n, 1, h, w))
    guide[0, 0, 0, :3] = [0.0, 1.0, 64 / GUIDE_RANGE]
    return values, guide


RATES = (2, 3, 64)  # D = 5, and several pixels per spatial cell


def test_grid_shape_covers_every_corner():
    assert grid_shape(720, 1280, (4, 4, 4)) == (65, 181, 321)  # the paper's 64 range cells, +1
    assert grid_shape(720, 1280, (16, 16, 16)) == (17, 46, 81)
    guide = torch.rand(1, 1, 13, 17)
    guide[0, 0, 0, 0] = 1.0
    index, weight, cells = corner_coords(guide, (4, 4, 4))
    assert index.min() >= 0 and index.max() < cells
    torch.testing.assert_close(weight.sum(dim=1), torch.ones(1, 13 * 17, 1))


def test_splat_matches_brute_force():
    values, guide = _splat_case()
    got = splat(torch.from_numpy(values), torch.from_numpy(guide), RATES).numpy()
    want = _brute_force_splat(values, guide, RATES)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    assert want[:, -1].sum() == pytest.approx(values.shape[0] * values.shape[2] * values.shape[3])


class _SplatModule(torch.nn.Module):
    def forward(self, values, guide):
        return splat(values, guide, RATES)


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_exported_splat_matches_brute_force_in_onnxruntime(tmp_path, threads):
    """The exported splat has no scatter at all (onnxruntime's ScatterElements with a reduction
    runs on one thread; ScatterND with one loses updates in parallel) and accumulates the many
    pixels of a cell exactly with any thread count; the trace was at another size (dynamic
    axes), and the block MatMuls run on every thread."""
    path = tmp_path / "splat.onnx"
    trace = [torch.rand(1, 3, 16, 20), torch.rand(1, 1, 16, 20)]
    torch.onnx.export(_SplatModule(), tuple(trace), str(path), dynamo=False, opset_version=17,
                      input_names=["values", "guide"], output_names=["grid"],
                      dynamic_axes={"values": {0: "N", 2: "H", 3: "W"}, "guide": {0: "N", 2: "H", 3: "W"}})
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert not {op for op in ops if op.startswith("Scatter")} and "MatMul" in ops
    values, guide = _splat_case(seed=threads)
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    got = sess.run(None, {"values": values.astype(np.float32), "guide": guide.astype(np.float32)})[0]
    want = _brute_force_splat(values, guide.astype(np.float32).astype(np.float64), RATES)
    np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5)


@pytest.mark.parametrize("normalization", NORMALIZATIONS)
def test_slice_at_cell_centres_returns_cell_values(normalization):
    """A pixel at m = eta_h·y, n = eta_w·x with guide eta_d·z/255 reads cell (z, y, x) alone:
    S/W there (both normalisations agree on a single cell)."""
    gen = torch.Generator().manual_seed(0)
    rates = (2, 3, 51)  # 255/51 = 5: range-cell centres are exact multiples
    h, w = 7, 10
    d, hg, wg = grid_shape(h, w, rates)
    grid = torch.rand(1, 4, d, hg, wg, generator=gen, dtype=torch.float64)
    grid[:, 3] += 0.5  # weight sums > 0
    zs = torch.randint(0, d - 1, (1, 1, h, w), generator=gen)
    out = slice_grid(grid, zs.double() * rates[2] / GUIDE_RANGE, rates, normalization)
    for m in range(0, h, rates[0]):
        for k in range(0, w, rates[1]):
            z, y, x = int(zs[0, 0, m, k]), m // rates[0], k // rates[1]
            torch.testing.assert_close(out[0, :, m, k], grid[0, :3, z, y, x] / grid[0, 3, z, y, x])


@pytest.mark.parametrize("normalization", NORMALIZATIONS)
def test_constant_image_round_trips(normalization):
    gen = torch.Generator().manual_seed(1)
    values = torch.full((2, 3, 11, 13), 0.7, dtype=torch.float64)
    guide = torch.rand(2, 1, 11, 13, generator=gen, dtype=torch.float64)
    for rates in [(4, 4, 4), (8, 8, 8), (2, 3, 64)]:
        out = slice_grid(splat(values, guide, rates), guide, rates, normalization)
        torch.testing.assert_close(out, values, rtol=1e-12, atol=1e-12)


def test_slice_far_from_any_data_is_zero_not_nan():
    values = torch.rand(1, 3, 8, 8, dtype=torch.float64)
    grid = splat(values, torch.zeros(1, 1, 8, 8, dtype=torch.float64), (4, 4, 4))
    for normalization in NORMALIZATIONS:
        out = slice_grid(grid, torch.ones(1, 1, 8, 8, dtype=torch.float64), (4, 4, 4), normalization)
        assert torch.equal(out, torch.zeros_like(out))


def test_gradcheck_splat_and_slice():
    gen = torch.Generator().manual_seed(2)
    rates = (2, 2, 64)
    values = torch.rand(1, 3, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    guide = (0.05 + 0.9 * torch.rand(1, 1, 5, 6, generator=gen, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda v, g: splat(v, g, rates), (values, guide))
    grid = splat(values, guide, rates).detach()
    grid[:, 3] += 0.2  # every cell non-empty: "cell" normalisation is smooth in the grid then
    grid.requires_grad_()
    for normalization in NORMALIZATIONS:
        assert torch.autograd.gradcheck(lambda gr, g: slice_grid(gr, g, rates, normalization), (grid, guide))
    # end to end: splat then slice at the same guide
    assert torch.autograd.gradcheck(lambda v, g: slice_grid(splat(v, g, rates), g, rates), (values, guide))


def test_outlier_removal_removes_a_firefly_and_keeps_smooth_images():
    yy, xx = torch.meshgrid(torch.linspace(0, 1, 16), torch.linspace(0, 1, 20), indexing="ij")
    smooth = torch.stack([0.5 + 0.3 * torch.sin(3 * xx + yy), 0.4 + 0.2 * yy, 0.3 + 0.1 * xx])[None].double()
    torch.testing.assert_close(remove_outliers(smooth), smooth, rtol=0, atol=0)
    spiky = smooth.clone()
    for m, k in [(5, 7), (0, 0), (15, 19)]:  # inside, and in two corners
        spiky[0, :, m, k] *= 100.0
    out = remove_outliers(spiky)
    # replaced by the neighbours' mean: close inside, one pixel's slope off in a corner
    for (m, k), tol in [((5, 7), 0.02), ((0, 0), 0.15), ((15, 19), 0.15)]:
        torch.testing.assert_close(out[0, :, m, k], smooth[0, :, m, k], rtol=tol, atol=0)
    mask = torch.ones_like(smooth, dtype=torch.bool)
    for m, k in [(5, 7), (0, 0), (15, 19)]:
        mask[..., m, k] = False
    assert torch.equal(out[mask], spiky[mask])


def test_blend_weights_are_in_0_1_and_sum_to_1():
    gen = torch.Generator().manual_seed(3)
    logits = torch.randn(2, 3, 5, 7, generator=gen) * 10
    logits[0, 0, 0, 0], logits[0, 1, 0, 1] = 1e4, -1e4
    ws = blend_weights(logits)
    assert len(ws) == 3
    total = ws[0] + ws[1] + ws[2]
    torch.testing.assert_close(total, torch.ones_like(total))
    assert all(torch.isfinite(w).all() and (w >= -1e-6).all() and (w <= 1 + 1e-6).all() for w in ws)
    want = torch.softmax(logits, dim=1)
    for i in range(3):
        torch.testing.assert_close(ws[i], want[:, i:i + 1], rtol=1e-5, atol=1e-6)


# ----------------------------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------------------------

def _tensors(model, n, h, w, seed=0):
    feeds = example_inputs(model, n, h, w, seed=seed)
    return [torch.from_numpy(feeds[k]) for k in model.input_names]


@pytest.mark.parametrize("name", NBG_SPECS)
def test_interface_shapes_and_constant_irradiance(name):
    spec = load_spec(name)
    torch.manual_seed(0)
    model = build_model(spec).eval()
    temporal = "temporal" in spec.stages
    assert [n for n, _ in model.named_children()] == list(spec.stages)
    assert spec.stages[-3:] == ("guide", "splat", "slice")
    assert model.state_channels == ({"accum": 3} if temporal else {})
    t = _tensors(model, 2, 13, 18)
    with torch.no_grad():
        outs = model(*t)
        assert outs[0].shape == (2, 3, 13, 18) and all(torch.isfinite(o).all() for o in outs)
        deployed = model.deploy()
        for a, b in zip(outs, deployed(*t)):
            assert torch.equal(a, b)
        names = model.input_names
        if model.params.outlier_removal:  # it would (rightly) clip the random albedo's highs
            t[names.index("albedo")] = torch.full_like(t[names.index("albedo")], 0.6)
        # what the spec (de)modulates by: lights by 1 (an emissive layer), the albedo clamped
        emissive = t[names.index("emissive")] if "emissive" in names else None
        albedo = modulation_albedo(t[names.index("albedo")], emissive, model.params.albedo_clamp)
        t[names.index("color")] = 0.7 * (albedo + ALBEDO_EPS)
        if temporal:
            t[names.index("history")] = torch.zeros_like(t[names.index("history")])
        out = model(*t)[0]
    torch.testing.assert_close(out, 0.7 * (albedo + ALBEDO_EPS), rtol=1e-5, atol=1e-6)


def test_temporal_state_is_the_accumulated_demodulated_radiance():
    model = build_model(load_spec("nbg-2l-3g")).eval()
    t = _tensors(model, 1, 9, 12, seed=4)
    names = model.input_names
    with torch.no_grad():
        _, accum = model(*t)
    # the weight is the one fed as accum_weight ([[state]] alpha, spp-aware), (1, 1, 1, 1)
    weight = t[names.index("accum_weight")]
    want = temporal_accumulate(demodulate(t[names.index("color")], t[names.index("albedo")]),
                               t[names.index("prev_accum")], t[names.index("history")], weight)
    torch.testing.assert_close(accum, want)
    assert tuple(weight.shape) == (1, 1, 1, 1)


def test_state_weight_is_fed_by_spp_and_a_fixed_alpha_without_it():
    """[[state]] alpha: the model blends with the accum_weight input, which the protocol fills
    with spp / (spp + history_spp) per item; a spec without it keeps the graph constant
    ([params].alpha) and no such input; the two weights may not disagree."""
    import re

    spec = load_spec("nbg-2l-1g")
    assert spec.input_names[-1] == "accum_weight" and spec.protocol.weights == (("accum_weight", 0.2, 1.0),)
    feeds = {"color": torch.zeros(2, 3, 4, 5)}
    spec.protocol.start(feeds, feeds["color"], spp=torch.tensor([1, 3]))
    torch.testing.assert_close(feeds["accum_weight"].reshape(-1), torch.tensor([0.5, 0.75]))
    plain = re.sub(r"(?m)^(alpha|history_spp) = .*# .*(unknown|else).*\n", "", spec.raw)
    fixed = parse_spec(plain, "n.toml")
    assert "accum_weight" not in fixed.input_names and not fixed.protocol.weights
    assert "accum_weight" not in build_model(fixed).input_names
    with pytest.raises(SpecError, match=r"accum alpha 0.5 differs from \[params\].alpha 0.2"):
        build_model(parse_spec(spec.raw.replace("alpha = 0.2          # the current frame's weight where",
                                                "alpha = 0.5          # the current frame's weight where"), "n.toml"))


def _lit_spec(clamp: bool = True):
    """nbg-2l-3g reading the emissive layer, with or without the albedo clamp."""
    raw = load_spec("nbg-2l-3g").raw.replace('"depth"]', '"depth", "emissive"]')
    return parse_spec(raw.replace('normalization = "cell"', f'normalization = "cell"\nalbedo_clamp = {str(clamp).lower()}'),
                      "nbg-lit.toml")


def test_lights_and_bright_albedo_demodulate_as_in_wskpn():
    """With ``emissive`` NBG demodulates a light by 1 (not its albedo of 0, whose colour / ALBEDO_EPS
    a grid cell shared with a dark wall spreads into it as a halo), its GuideNet sees an 11th
    channel, and ``albedo_clamp`` re-modulates a rough conductor's albedo AOV of 58 by 1. The
    accumulated state is the irradiance under that same albedo, so it round-trips exactly."""
    torch.manual_seed(0)
    lit = build_model(_lit_spec()).eval()
    plain = build_model(load_spec("nbg-2l-3g")).eval()
    first = [[m for m in x.guide.modules() if isinstance(m, torch.nn.Conv2d)][0] for x in (plain, lit)]
    assert (first[0].in_channels, first[1].in_channels) == (10, 11)
    assert lit.params.albedo_clamp and not plain.params.albedo_clamp

    def scene(model, conductor=False):
        t = _tensors(model, 1, 16, 16)
        names = model.input_names
        t[names.index("albedo")][:] = 0.7
        t[names.index("albedo")][..., :8] = 0.0
        t[names.index("color")][:] = 0.01
        t[names.index("color")][..., :8] = 15.7
        t[names.index("history")][:] = 0.0
        if conductor:
            t[names.index("albedo")][..., 8:] = 58.0
        if "emissive" in names:
            t[names.index("emissive")][:] = 0.0
            t[names.index("emissive")][..., :8] = 1.0
        return t

    bound = 15.7 * (0.7 + ALBEDO_EPS) + 1e-4      # a wall pixel at most the light's own value
    with torch.no_grad():
        assert float(plain(*scene(plain))[0][..., 8:].max()) > 10 * bound   # the halo, without the layer
        t = scene(lit)
        out, accum = lit(*t)
        assert float(out[..., 8:].max()) <= bound
        assert float(out[..., :8].min()) >= 0.01 * (1 + ALBEDO_EPS) - 1e-6
        names = lit.input_names
        m = modulation_albedo(t[names.index("albedo")], t[names.index("emissive")], clamp=True)
        want = temporal_accumulate(demodulate(t[names.index("color")], m), t[names.index("prev_accum")],
                                   t[names.index("history")], t[names.index("accum_weight")])
        torch.testing.assert_close(accum, want)
        out = lit(*scene(lit, conductor=True))[0]
        assert float(out[..., 8:].max()) <= 15.7 * (1 + ALBEDO_EPS) + 1e-4
        unclamped = build_model(_lit_spec(clamp=False)).eval()
        unclamped.load_state_dict(lit.state_dict())
        assert float(unclamped(*scene(unclamped, conductor=True))[0][..., 8:].max()) > 15.7 * 1.5


def test_params_and_builder_are_validated():
    raw = load_spec("nbg-2l-3g").raw
    with pytest.raises(SpecError, match=r"\[params\]: grids: must be 1..4"):
        build_model(parse_spec(raw.replace("grids = 3", "grids = 0"), "n.toml"))
    with pytest.raises(SpecError, match=r"\[params\]: rates: need \[eta_h, eta_w, eta_d\]"):
        build_model(parse_spec(raw.replace("rates = [4, 4, 4]", "rates = [4, 4]"), "n.toml"))
    with pytest.raises(SpecError, match=r"\[params\]\.normalization: expected one of"):
        build_model(parse_spec(raw.replace('normalization = "cell"', 'normalization = "box"'), "n.toml"))
    with pytest.raises(SpecError, match=r"stages must be \['temporal', 'guide', 'splat', 'slice'\]"):
        build_model(parse_spec(raw.replace('"guide", "splat", "slice"', '"guide", "slice", "splat"'), "n.toml"))
    with pytest.raises(SpecError, match=r"\[\[state\]\] must be"):
        build_model(parse_spec(raw.replace("channels = 3", "channels = 1"), "n.toml"))
    with pytest.raises(ValueError, match="dense GuideNet needs >= 3 layers"):
        NBGParams(layers=2, dense=True)
    assert NBGParams().scale_rates(2) == (16, 16, 16)


def test_three_training_steps(tiny_dataset, tmp_path):
    from mcdenoise.training import runs
    from mcdenoise.training.train import train

    row = train("nbg-2l-3g", tiny_dataset, tmp_path / "run", steps=3, crop=32, batch_size=2, quiet=True,
                val_every=0)
    assert np.isfinite(row["val_psnr"]) and runs.read_metrics(tmp_path / "run")[-1]["final"]
