"""ANF and the per-sample input path: the kernels against a brute-force sum, the run-time kernel
size and the sample count through the ONNX file against torch, the embedding's invariances,
the driver against the training unroll, settings, and the one-line error on plain input.

Uses a randomly initialised (seeded) anf-s: behaviour, not quality, is under test here."""
import numpy as np
import pytest
import torch

from mcdenoise.export.onnx_export import export_model, parity_errors, parity_ok
from mcdenoise.runtime.contract import SAMPLES_INPUT
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import SAMPLE_GROUPS, Frame, FrameError
from mcdenoise.runtime.inputs import sample_channels, sample_inputs
from mcdenoise.training.harness import synthetic_frame
from mcdenoise.training.models import example_inputs
from mcdenoise.training.models.anf import AFFINITY_BOUND, affinity_sums, affinity_sums_eager
from mcdenoise.training.specs import build_model, load_spec

SPEC = "anf-s"


@pytest.fixture(scope="module")
def anf(tmp_path_factory):
    torch.manual_seed(0)
    spec = load_spec(SPEC)
    model = build_model(spec).eval()
    path = tmp_path_factory.mktemp("anf") / f"{SPEC}.onnx"
    export_model(spec, model, path)
    return path, spec, model


def _brute(x, f, g, a, mask, k, dilation, skip_centre):
    n, c, h, w = x.shape
    num, den = np.zeros_like(x), np.zeros_like(a)
    r = k // 2
    for y in range(h):
        for xx in range(w):
            for i in range(-r, r + 1):
                for j in range(-r, r + 1):
                    v, u = y + i * dilation, xx + j * dilation
                    if not (0 <= v < h and 0 <= u < w) or (skip_centre and i == 0 and j == 0):
                        continue
                    e = a[:, 0, y, xx] * ((f[:, :, y, xx] - g[:, :, v, u]) ** 2).sum(1)
                    wt = np.exp(-np.minimum(e, AFFINITY_BOUND)) * mask[:, 0, v, u]
                    num[:, :, y, xx] += wt[:, None] * x[:, :, v, u]
                    den[:, 0, y, xx] += wt
    return num, den


@pytest.mark.parametrize("sums", [affinity_sums, affinity_sums_eager], ids=["script", "eager"])
@pytest.mark.parametrize("k,dilation,skip", [(3, 1, True), (5, 2, False), (3, 4, True)])
def test_affinity_sums_equal_the_brute_force_sum(k, dilation, skip, sums):
    """Both forms of the one function: TorchScript (exported) and eager (trained)."""
    rng = np.random.default_rng(k + dilation)
    x, f, g = rng.random((2, 3, 9, 11)), rng.normal(size=(2, 4, 9, 11)), rng.normal(size=(2, 4, 9, 11))
    f[0, :, :3] *= 10.0                            # some exponents beyond the bound
    a, mask = rng.random((2, 1, 9, 11)), (rng.random((2, 1, 9, 11)) > 0.3).astype(np.float64)
    got = sums(*[torch.from_numpy(v) for v in (x, f, g, a, mask)], torch.tensor(k), dilation, skip, AFFINITY_BOUND)
    for gv, want in zip(got, _brute(x, f, g, a, mask, k, dilation, skip)):
        np.testing.assert_allclose(gv.numpy(), want, rtol=1e-12, atol=1e-12)


def test_zero_bandwidth_and_full_centre_weight_is_a_box_filter():
    from mcdenoise.training.models.anf import spatial_filter

    x = torch.rand(1, 3, 8, 10, dtype=torch.float64)
    f = torch.randn(1, 4, 8, 10, dtype=torch.float64)
    zero, one = torch.zeros(1, 1, 8, 10, dtype=torch.float64), torch.ones(1, 1, 8, 10, dtype=torch.float64)
    num, den = spatial_filter(x, f, zero, one, torch.tensor(3), 1)
    box = torch.nn.functional.avg_pool2d(x, 3, 1, 1, count_include_pad=False)
    torch.testing.assert_close(num / den, box)
    # the centre weight alone decides the centre's share: c = 0 drops the pixel itself
    num0, den0 = spatial_filter(x, f, zero, zero, torch.tensor(3), 1)
    assert torch.allclose(den0, den - 1)


@pytest.mark.parametrize("k", [3, 7, 13, 19])
def test_kernel_size_is_a_run_time_input_equal_to_torch_at_each_size(anf, k):
    path, _, model = anf
    den = Denoiser.load(path)
    feeds = example_inputs(model, 1, 30, 41, seed=3, spp=2)
    feeds["kernel_size"] = np.array(k, np.int64)
    errors = parity_errors(model, lambda f: den.session.run(list(model.output_names), f), feeds)
    assert parity_ok(errors), errors


def test_kernel_size_changes_the_output_and_is_validated(anf):
    path, _, model = anf
    feeds = example_inputs(model, 1, 24, 24, seed=4)
    sess = Denoiser.load(path).session
    outs = {k: sess.run(["output"], {**feeds, "kernel_size": np.array(k, np.int64)})[0] for k in (3, 13)}
    assert np.abs(outs[3] - outs[13]).mean() > 1e-3 * np.abs(outs[13]).mean()
    den = Denoiser.load(path, settings={"kernel_size": 7})
    assert den.settings == {"kernel_size": 7}
    for bad in (4, 1, 21, "7"):
        with pytest.raises(ValueError, match="kernel_size must be one of 3, 5, ... 19"):
            den.set("kernel_size", bad)
    with pytest.raises(ValueError, match="has no setting 'radius'"):
        den.set("radius", 3)
    assert den.contract.settings[0] == {"name": "kernel_size", "input": "kernel_size", "default": 13, "min": 3,
                                        "max": 19, "step": 2}


@pytest.mark.parametrize("spp", [1, 7])
def test_the_sample_axis_is_dynamic(anf, spp):
    path, _, model = anf
    feeds = example_inputs(model, 2, 20, 26, seed=spp, spp=spp)
    assert feeds[SAMPLES_INPUT].shape == (2, spp, 18, 20, 26)
    sess = Denoiser.load(path).session
    errors = parity_errors(model, lambda f: sess.run(list(model.output_names), f), feeds)
    assert parity_ok(errors), errors


def test_embedding_is_a_mean_over_samples(anf):
    """Eq. 1: the order of the samples does not matter, and repeating every sample does not
    change the per-pixel embedding (the depth feature is normalised over all samples)."""
    _, _, model = anf
    s = torch.from_numpy(example_inputs(model, 1, 16, 16, spp=3)[SAMPLES_INPUT])
    with torch.no_grad():
        e = model.embedding(s)
        torch.testing.assert_close(model.embedding(s[:, [2, 0, 1]]), e)
        torch.testing.assert_close(model.embedding(torch.cat([s, s], dim=1)), e)
    assert e.shape == (1, 32, 16, 16)


def test_driver_matches_the_training_unroll(anf):
    """Three frames with per-sample data through the driver and through train.run_window: the
    same samples input (sanitised, screen normals, exposed radiance), state and outputs."""
    from mcdenoise.training.train import run_window

    path, spec, model = anf
    frames = [Frame(**synthetic_frame(20, 16, t, spp=3)) for t in range(3)]
    den = Denoiser.load(path, log=lambda m: None)
    outs = [den(f) for f in frames]
    groups = [g for g, _ in spec.inputs.sample_groups]
    batch = {}
    from mcdenoise.runtime.inputs import frame_inputs

    for f in frames:
        arrays = frame_inputs(f, ["color", "motion", "position", "normal", "depth"])
        arrays["normal_world"] = f.normal.transpose(2, 0, 1)[None].copy()
        arrays["samples"] = sample_inputs(f, groups)
        for k, v in arrays.items():
            batch.setdefault(k, []).append(torch.from_numpy(v))
    batch = {k: torch.stack(v, dim=1) for k, v in batch.items()}
    batch["spp"] = torch.tensor([3.0])       # the driver knows each frame's spp: the bound on λ
    with torch.no_grad():
        ref = run_window(model, batch, spec.protocol)
    for t in range(3):
        np.testing.assert_allclose(outs[t], ref[t]["output"][0].numpy().transpose(1, 2, 0), rtol=2e-4, atol=2e-5)
    # the history is used: the third frame differs from the same frame without one
    fresh = Denoiser.load(path, log=lambda m: None)(frames[2])
    assert np.abs(fresh - outs[2]).mean() > 1e-4


def test_sample_inputs_sanitise_expose_and_rotate_normals():
    fr = Frame(**synthetic_frame(8, 6, 0, spp=2))
    fr.samples[0, 1, 2, SAMPLE_GROUPS["radiance"].start] = np.nan
    fr.samples[1, 3, 4, SAMPLE_GROUPS["radiance"].start + 1] = -5.0
    fr.samples[0, 0, 0, SAMPLE_GROUPS["depth"].start] = np.inf
    groups = ["diffuse_radiance", "normal", "depth"]
    from mcdenoise.runtime.inputs import SanitizeReport

    rep = SanitizeReport()
    x = sample_inputs(fr, groups, rep, scale=2.0)
    assert x.shape == (1, 2, 7, 6, 8) and np.isfinite(x).all() and (x[:, :, :3] >= 0).all()
    assert rep.nonfinite and rep.negative
    assert sample_channels(groups, "radiance") == [0, 1, 2] and sample_channels(groups, "screen_xy") == [3, 4]
    clean = sample_inputs(Frame(**synthetic_frame(8, 6, 0, spp=2)), groups, None, scale=2.0)
    diffuse = fr.sample_feature("diffuse_radiance")[1, 2, 2]
    np.testing.assert_allclose(clean[0, 1, :3, 2, 2], 2.0 * diffuse, rtol=1e-6)
    # the identity camera's screen frame flips x and y of the world normal (-z here stays -z)
    np.testing.assert_allclose(clean[0, 0, 3:6, 0, 0], [0.0, 0.0, -1.0], atol=1e-6)


def test_a_per_sample_model_on_plain_input_says_what_it_needs(anf):
    path, _, _ = anf
    den = Denoiser.load(path, log=lambda m: None)
    fr = Frame(**synthetic_frame(16, 12, 0))
    with pytest.raises(FrameError, match=r"reads per-sample data \(sample<i>\.\* layers\) and the frame has none"):
        den(fr)
    assert den.report.frames == 0


def test_the_denoise_command_on_plain_images_says_it_needs_samples_in_one_line(anf, tmp_path, capsys):
    from mcdenoise.runtime.cli import main
    from mcdenoise.runtime.writers import write_rgb

    path, _, _ = anf
    write_rgb(tmp_path / "color.exr", synthetic_frame(16, 12, 0)["color"])
    args = ["denoise", "--model", str(path), "--input", str(tmp_path / "color.exr"), "--output", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "reads per-sample data" in err[0] and "mcdenoise render" in err[0]
    assert "Traceback" not in err[0]


def test_loop_bodies_are_not_counted_twice_in_the_stage_times(tmp_path):
    """A profiled Loop records its body's kernels inside its own span: the stage sums count
    the Loop once (a synthetic onnxruntime profile: run 0-100, unet 0-10, Loop 10-90 with two
    body kernels, a last kernel 90-95)."""
    import json

    from mcdenoise.runtime.timing import graph_stage_times

    def node(name, ts, dur):
        return {"cat": "Node", "name": name + "_kernel_time", "ts": ts, "dur": dur}

    events = [{"name": "model_run", "ts": 0, "dur": 100_000}, node("/unet/Conv", 0, 10_000),
              node("/kernels/Loop", 10_000, 80_000), node("Mul_3", 11_000, 30_000), node("Add_4", 41_000, 40_000),
              node("/kernels/Div", 90_000, 5_000)]
    path = tmp_path / "p.json"
    path.write_text(json.dumps(events))
    assert graph_stage_times(str(path), ["embedding", "unet", "kernels"]) == [
        {"embedding": 0.0, "unet": 10.0, "kernels": 85.0}]


def _arrays(obj, seen=None):
    """Every numpy array reachable from ``obj`` through dicts, lists, tuples and attributes."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return []
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return [obj]
    if isinstance(obj, dict):
        items = list(obj.values())
    elif isinstance(obj, (list, tuple)):
        items = list(obj)
    elif hasattr(obj, "__dict__") and type(obj).__module__.startswith("mcdenoise"):
        items = list(vars(obj).values())
    else:
        return []
    return [a for x in items for a in _arrays(x, seen)]


def test_the_driver_keeps_no_samples_between_frames(anf):
    """What the driver holds after a frame: its declared state, the guide planes and its plane
    buffers, nothing of the frame's per-sample data (8 spp: 8 x 18 floats per pixel)."""
    path, spec, _ = anf
    den = Denoiser.load(path, log=lambda m: None)
    h, w = 24, 32
    for t in range(2):
        den(Frame(**synthetic_frame(w, h, t, spp=8)))
    held = sum(a.nbytes for a in _arrays(den))
    state = sum(s.channels for s in spec.state) * h * w * 4
    assert held < state + 40 * h * w * 4                # state, guides, the two plane-buffer sets
    assert held < 8 * 18 * h * w * 4


@pytest.mark.parametrize("name,params", [("anf", 942_240), ("anf-s", 134_016)])
def test_parameter_counts_are_what_the_readme_says(name, params):
    """The README and model card quote these; anf's matches the paper's 0.94 million (§5.4)."""
    assert sum(p.numel() for p in build_model(load_spec(name)).parameters()) == params


def test_the_fed_weight_bounds_lambda_for_embedding_and_radiance(anf):
    """λ = min(sigmoid(x), 1 − weight)·history for ē and L̄ alike: with the previous state one
    above the current frame, the next state minus the frame is λ itself."""
    _, spec, model = anf
    assert "embed_weight" in model.input_names      # the shipped spec bounds λ (history_spp)
    torch.manual_seed(1)
    n, h, w = 3, 6, 7
    params = torch.randn(n, model.params_.outputs, h, w) * 3.0
    e, color = torch.rand(n, 32, h, w), torch.rand(n, 3, h, w)
    zeros3, zeros8, ones = torch.zeros(n, 3, h, w), torch.zeros(n, 8, h, w), torch.ones(n, 1, h, w)
    weight = torch.tensor([0.0, 0.5, 1.0]).reshape(n, 1, 1, 1)
    with torch.no_grad():
        out = model.kernels(params, e, color, e + 1, color + 1, zeros8, zeros3, ones, torch.tensor(3), weight)
        free = model.kernels(params, e, color, e + 1, color + 1, zeros8, zeros3, ones, torch.tensor(3), None)
    lam = torch.minimum(torch.sigmoid(params[:, -1:]), 1 - weight)
    torch.testing.assert_close(out[1] - e, lam.expand_as(e))
    torch.testing.assert_close(out[2] - color, lam.expand_as(color))
    torch.testing.assert_close(out[1][0], free[1][0])           # weight 0: the learned λ untouched
    torch.testing.assert_close(out[1][2], e[2])                 # weight 1: no history kept
    assert (free[1][1] - e[1]).max() > 0.51 and (out[1][1] - e[1]).max() <= 0.5 + 1e-6   # it binds somewhere


def test_the_file_tells_the_driver_which_weight_to_feed(anf):
    """The contract names the fed weight with the spec's rule (the driver's feeding of it is
    test_driver_matches_the_training_unroll: a frame of known spp against the trainer's)."""
    path, spec, _ = anf
    embed = spec.state[0]
    assert embed.name == "embed" and embed.history_spp > 0 and 0 < embed.alpha <= 1
    state = {s["name"]: s for s in Denoiser.load(path, log=lambda m: None).contract.state}
    assert state["embed"]["weight_input"] == "embed_weight"
    assert (state["embed"]["alpha"], state["embed"]["history_spp"]) == (embed.alpha, embed.history_spp)
    assert all("weight_input" not in state[k] for k in ("radiance", "features", "output"))


def test_a_weight_on_another_state_is_refused():
    from mcdenoise.training.specs import SpecError, parse_spec

    text = load_spec(SPEC).path.read_text().replace('name = "output"          # O of the last frame, Eq. 8\nchannels = 3',
                                                    'name = "output"\nchannels = 3\nalpha = 0.5')
    assert "alpha = 0.5" in text
    with pytest.raises(SpecError, match="only on \\[\\[state\\]\\] 'embed'"):
        build_model(parse_spec(text, "bad.toml"))


def _anf_pair():
    """anf-s and anf-sd (the demodulating spec) with the same seeded weights."""
    torch.manual_seed(5)
    plain = build_model(load_spec("anf-s")).eval()
    demod = build_model(load_spec("anf-sd")).eval()
    demod.load_state_dict(plain.state_dict())          # the same weights fit: --init anf-s -> anf-sd
    return plain, demod


def test_demodulation_keeps_a_texture_the_plain_kernels_blur():
    """Constant irradiance under a checkerboard albedo: the demodulating spec filters a constant
    and re-modulates it, so it returns the texture exactly whatever its weights; the same
    weights on the radiance average the checks into each other."""
    plain, demod = _anf_pair()
    feeds = example_inputs(demod, 1, 24, 32, seed=6, spp=2)
    yy, xx = np.meshgrid(np.arange(24), np.arange(32), indexing="ij")
    albedo = np.where((yy // 2 + xx // 2) % 2, 0.8, 0.2)[None, None].repeat(3, axis=1).astype(np.float32)
    feeds["albedo"] = albedo
    feeds["emissive"] = np.zeros_like(feeds["emissive"])
    feeds["color"] = (0.7 * (albedo + 1e-2)).astype(np.float32)       # ALBEDO_EPS
    feeds["history"] = np.zeros_like(feeds["history"])
    t = {k: torch.from_numpy(v) for k, v in feeds.items()}
    with torch.no_grad():
        out = demod(*[t[n] for n in demod.input_names])[0].numpy()
        blur = plain(*[t[n] for n in plain.input_names])[0].numpy()
    np.testing.assert_allclose(out, feeds["color"], rtol=1e-5)
    assert np.abs(blur - feeds["color"]).mean() > 0.05 * feeds["color"].mean()


def test_demodulation_by_white_albedo_is_the_plain_model():
    """With albedo 1 everywhere demodulating divides by a constant the linear kernels carry
    through: the output is anf-s's, the radiance and output states 1 / (1 + ε) of anf-s's."""
    plain, demod = _anf_pair()
    feeds = example_inputs(demod, 2, 20, 24, seed=7, spp=3)
    feeds["albedo"] = np.ones_like(feeds["albedo"])
    t = {k: torch.from_numpy(v) for k, v in feeds.items()}
    # the demodulating model's radiance and output states hold irradiance
    td = {**t, **{k: t[k] / (1 + 1e-2) for k in ("prev_radiance", "prev_output")}}
    with torch.no_grad():
        out = demod(*[td[n] for n in demod.input_names])
        ref = plain(*[t[n] for n in plain.input_names])
    torch.testing.assert_close(out[0], ref[0], rtol=2e-5, atol=1e-6)
    torch.testing.assert_close(out[2] * (1 + 1e-2), ref[2], rtol=2e-5, atol=1e-6)     # next_radiance


def test_dark_albedo_bounds_the_irradiance_of_black_pixels():
    from mcdenoise.runtime.inputs import ALBEDO_EPS
    from mcdenoise.training.models.anf import DARK_ALBEDO
    from mcdenoise.training.models.common import dark_albedo

    a = torch.tensor([0.0, 0.01, 0.05, 0.1, 0.3, 1.0]).reshape(1, 1, 6, 1).expand(1, 3, 6, 1)
    m = dark_albedo(a, DARK_ALBEDO)
    assert float((1.0 / (m + ALBEDO_EPS)).max()) <= 1.0 / DARK_ALBEDO    # not 1 / ALBEDO_EPS = 100x
    assert bool((m[0, 0, 1:4, 0] < m[0, 0, 0:3, 0]).all())        # from 1 at black down to dark
    torch.testing.assert_close(m[:, :, 3:], a[:, :, 3:])          # exactly the albedo from dark up
    torch.testing.assert_close(m[:, :, 0], torch.ones(1, 3, 1))   # a miss: by 1, as the plain model
    # continuous at dark: a hair below it is a hair below the albedo
    near = dark_albedo(torch.full((1, 3, 1, 1), DARK_ALBEDO * 0.999), DARK_ALBEDO)
    assert abs(float(near[0, 0, 0, 0]) - DARK_ALBEDO) < 2e-3


def test_an_anf_spec_reads_color_then_optionally_albedo_and_emissive():
    from mcdenoise.training.specs import SpecError, parse_spec

    text = load_spec("anf-sd").path.read_text()
    for layers in ('["color", "normal"]', '["albedo", "color"]', '["color", "emissive"]'):
        bad = text.replace('layers = ["color", "albedo", "emissive"]', f"layers = {layers}")
        assert bad != text
        with pytest.raises(SpecError, match="reads \\[inputs\\].layers = one of"):
            build_model(parse_spec(bad, "bad.toml"))


def test_training_mode_runs_the_eager_kernels_to_the_same_output(anf):
    """Training runs affinity_sums_eager, export and inference the TorchScript form: one model's
    output is the same in both modes (the only difference between them)."""
    _, _, model = anf
    feeds = {k: torch.from_numpy(v) for k, v in example_inputs(model, 2, 20, 22, seed=8, spp=2).items()}
    with torch.no_grad():
        ref = model.eval()(*[feeds[n] for n in model.input_names])
        got = model.train()(*[feeds[n] for n in model.input_names])
    model.eval()
    for r, g in zip(ref, got):
        torch.testing.assert_close(g, r, rtol=1e-5, atol=1e-6)
