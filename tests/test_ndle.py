"""NDLE on the per-sample input path: the splat against a brute-force scatter, energy
conservation of the layered composite, invariance to the order and repetition of samples, the
sample axis through the ONNX file, the driver against torch, and the plain-input error.

Uses a randomly initialised (seeded) ndle-s: behaviour, not quality, is under test here."""
import numpy as np
import pytest
import torch

from mcdenoise.export.onnx_export import export_model, parity_errors, parity_ok
from mcdenoise.runtime.contract import SAMPLES_INPUT
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import Frame, FrameError
from mcdenoise.runtime.inputs import sample_inputs
from mcdenoise.training.harness import synthetic_frame
from mcdenoise.training.models import example_inputs
from mcdenoise.training.models.ndle import LOGIT_BOUND, splat
from mcdenoise.training.specs import build_model, load_spec

SPEC = "ndle-s"


@pytest.fixture(scope="module")
def ndle(tmp_path_factory):
    torch.manual_seed(0)
    spec = load_spec(SPEC)
    model = build_model(spec).eval()
    path = tmp_path_factory.mktemp("ndle") / f"{SPEC}.onnx"
    export_model(spec, model, path)
    return path, spec, model


def test_splat_equals_the_brute_force_scatter():
    """Each source pixel q spreads exp(logit_t(q))·x(q) to q + offset_t; nothing comes from
    outside the frame, and what would land outside is dropped."""
    rng = np.random.default_rng(0)
    k, r = 5, 2
    x = rng.normal(size=(2, 3, 7, 9))
    logits = rng.normal(scale=3.0, size=(2, k * k, 7, 9))
    logits[0, 3, 1, 1] = 40.0                          # beyond the bound: clamped
    want = np.zeros_like(x)
    wts = np.exp(np.clip(logits, -LOGIT_BOUND, LOGIT_BOUND))
    for b in range(2):
        for qy in range(7):
            for qx in range(9):
                for t in range(k * k):
                    py, px = qy + t // k - r, qx + t % k - r
                    if 0 <= py < 7 and 0 <= px < 9:
                        want[b, :, py, px] += wts[b, t, qy, qx] * x[b, :, qy, qx]
    got = splat(torch.from_numpy(x), torch.from_numpy(logits), k).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10)


def test_unfiltered_layers_composite_to_the_mean_of_the_samples(ndle):
    """Kernels that keep every source in its own pixel and λ on the full scale: the composite
    of the layers is the samples' mean radiance, whatever the partition (Eq. 2-5 conserve
    energy by construction)."""
    import copy

    _, _, model = ndle
    m = copy.deepcopy(model)
    taps, centre = m.params_.kernel ** 2, m.params_.kernel ** 2 // 2
    with torch.no_grad():
        for i, gen in enumerate(m.layer_filtering.generators):
            last = gen.rest[-1]
            last.weight.zero_()
            last.bias.fill_(-LOGIT_BOUND)
            last.bias[centre] = LOGIT_BOUND
            if i == 0:
                last.bias[taps:] = torch.tensor([30.0, -30.0, -30.0])
        # a partition that differs per sample (the partitioner keeps its random weights)
    feeds = example_inputs(m, 1, 20, 24, spp=4)
    s = torch.from_numpy(feeds[SAMPLES_INPUT]).double()
    m = m.double()
    with torch.no_grad():
        out = m(s)[0]
    mean = s[:, :, 0:3].mean(dim=1)                    # ndle-s lists radiance first
    # exp(-30) of the coarse scales and e^-30 of the neighbours' taps remain
    torch.testing.assert_close(out, mean, rtol=1e-9, atol=1e-9)


def test_the_output_ignores_the_order_and_repetition_of_samples(ndle):
    _, _, model = ndle
    s = torch.from_numpy(example_inputs(model, 1, 16, 20, spp=3)[SAMPLES_INPUT])
    with torch.no_grad():
        out = model(s)[0]
        torch.testing.assert_close(model(s[:, [2, 0, 1]])[0], out, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(model(torch.cat([s, s], dim=1))[0], out, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("spp,h,w", [(1, 20, 26), (7, 17, 30)])
def test_the_sample_axis_and_size_are_dynamic(ndle, spp, h, w):
    path, _, model = ndle
    feeds = example_inputs(model, 2, h, w, seed=spp, spp=spp)
    assert feeds[SAMPLES_INPUT].shape == (2, spp, 18, h, w)
    sess = Denoiser.load(path, log=lambda m: None).session
    errors = parity_errors(model, lambda f: sess.run(list(model.output_names), f), feeds)
    assert parity_ok(errors), errors


def test_the_driver_matches_torch_on_a_frame(ndle):
    """A frame with per-sample data through the driver equals the model on the same samples
    input (sanitised, screen normals, exposed radiance) and back to the frame's exposure."""
    path, spec, model = ndle
    den = Denoiser.load(path, log=lambda m: None)
    frames = [Frame(**synthetic_frame(20, 16, t, spp=3)) for t in range(2)]
    groups = [g for g, _ in spec.inputs.sample_groups]
    for f in frames:
        out = den(f)
        scale = None if den.exposure == 1.0 else den.exposure
        x = sample_inputs(f, groups, scale=scale)
        with torch.no_grad():
            ref = model(torch.from_numpy(x))[0][0].numpy().transpose(1, 2, 0)
        if scale is not None:
            ref = ref / scale
        np.testing.assert_allclose(out, ref, rtol=2e-4, atol=2e-5)
    assert den.report.frames == 2


def test_a_per_sample_model_on_plain_input_says_what_it_needs(ndle):
    path, _, _ = ndle
    den = Denoiser.load(path, log=lambda m: None)
    with pytest.raises(FrameError, match=r"reads per-sample data \(sample<i>\.\* layers\) and the frame has none"):
        den(Frame(**synthetic_frame(16, 12, 0)))
    assert den.report.frames == 0


def test_training_steps_and_the_export_from_the_run(tiny_dataset, tmp_path):
    from mcdenoise.export.onnx_export import export_run
    from mcdenoise.training.train import train

    run = tmp_path / "run"
    row = train(SPEC, tiny_dataset, run, steps=3, crop=32, batch_size=2, quiet=True, val_every=0)
    assert np.isfinite(row["val_psnr"])
    export_run(run, tmp_path / "n.onnx")
    assert Denoiser.load(tmp_path / "n.onnx", log=lambda m: None).contract.spec_name == SPEC


def test_parameter_count_is_what_the_model_card_says():
    assert sum(p.numel() for p in build_model(load_spec(SPEC)).parameters()) == 140_288


def test_later_frames_do_not_grow_a_per_sample_models_memory(ndle):
    """onnxruntime's memory pattern, planned at the first run, is allocated beside the arena that
    run filled; with it a per-sample model's second frame held about twice the first's working
    memory (ndle-s at 1280x720 x 8 spp: 4.0 then 8.2 GB, docs/results/ndle/mem_pattern.py). The driver turns it off for per-sample
    models: the peak resident set after three frames stays near the one after the first."""
    import subprocess
    import sys

    path, _, _ = ndle
    script = f"""
import json
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.training.harness import synthetic_frame
from mcdenoise.training.memory import _maxrss_mb
frames = [synthetic_frame(384, 256, t, spp=8) for t in range(3)]
den = Denoiser.load({str(path)!r}, threads=1, log=lambda m: None)
assert den.session.get_session_options().enable_mem_pattern is False
base = _maxrss_mb(); den(frames[0]); first = _maxrss_mb()
den(frames[1]); den(frames[2])
print(json.dumps([base, first, _maxrss_mb()]))
"""
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    base, first, last = (float(v) for v in p.stdout.strip().splitlines()[-1].strip("[]").split(","))
    assert last - first < 0.25 * (first - base), (base, first, last)
