"""The timing harness of the measuring side: methods timed frame by frame, interleaved, on a
synthetic sequence with history; torch eager per stage; Open Image Denoise on CUDA; and the
compute count of Open Image Denoise's published U-Net.

Times are medians of ``frames`` timed frames after ``warmup`` untimed ones; every method runs
in the same loop (one frame each in turn) so the machine's drift hits all of them alike."""
from __future__ import annotations

import statistics
import time

import numpy as np

from mcdenoise.runtime import timing

#: Open Image Denoise's U-Net as published in its training code (RenderKit/oidn
#: training/model.py, class UNet; the same layer sequence core/unet_filter.cpp builds): 3x3
#: convolutions as (name, input channels, output channels, resolution divisor); ``IC`` is the
#: input channel count (9: colour, albedo, normal).  2x2 max pools and nearest upsampling
#: between levels.  Images are padded to multiples of 16.
OIDN_UNET = (("enc_conv0", "IC", 32, 1), ("enc_conv1", 32, 32, 1), ("enc_conv2", 32, 48, 2),
             ("enc_conv3", 48, 64, 4), ("enc_conv4", 64, 80, 8), ("enc_conv5a", 80, 96, 16),
             ("enc_conv5b", 96, 96, 16), ("dec_conv4a", 96 + 64, 112, 8), ("dec_conv4b", 112, 112, 8),
             ("dec_conv3a", 112 + 48, 96, 4), ("dec_conv3b", 96, 96, 4), ("dec_conv2a", 96 + 32, 64, 2),
             ("dec_conv2b", 64, 64, 2), ("dec_conv1a", "64+IC", 64, 1), ("dec_conv1b", 64, 32, 1),
             ("dec_conv0", 32, 3, 1))


def oidn_unet_count(w: int, h: int, in_channels: int = 9) -> dict:
    """FMAs, FLOPs (2 per FMA + bias adds + ReLUs + pool compares, the rules of
    :mod:`training.flops`) and parameters of :data:`OIDN_UNET` on a ``w`` x ``h`` image."""
    pw, ph = -(-w // 16) * 16, -(-h // 16) * 16
    fmas = flops = params = 0
    for name, cin, cout, div in OIDN_UNET:
        cin = {"IC": in_channels, "64+IC": 64 + in_channels}.get(cin, cin)
        px = (pw // div) * (ph // div)
        f = px * cout * cin * 9
        fmas += f
        flops += 2 * f + px * cout * (1 if name == "dec_conv0" else 2)   # bias (+ ReLU)
        if name in ("enc_conv1", "enc_conv2", "enc_conv3", "enc_conv4"):
            flops += (px // 4) * cout * 4                                  # 2x2 max pool
        params += cout * cin * 9 + cout
    return {"fmas": fmas, "flops": flops, "params": params, "padded": f"{pw}x{ph}"}


#: Camera pan of the synthetic timing sequence, pixels per frame: sub-pixel, so reprojection
#: blends all four bilinear taps as it does for a real camera (an integer pan would let the
#: driver skip three of them).
SYNTHETIC_PAN = (0.7, 0.3)


def synthetic_frame(w: int, h: int, t: int, seed: int = 0, spp: int = 0) -> dict:
    """A plausible frame: smooth albedo/normals, noisy colour, a slow sub-pixel pan
    (:data:`SYNTHETIC_PAN`) over a plane 5-6 units away whose world positions move with it,
    so the reprojection's consistency test passes as on a real surface.  ``spp`` > 0 adds
    that many per-sample features (``samples``, for per-sample models) and makes ``color``
    their mean, as a render does."""
    rng = np.random.default_rng(seed + t)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    albedo = np.stack([0.5 + 0.3 * np.sin(xx / 17), 0.5 + 0.3 * np.cos(yy / 23), np.full_like(xx, 0.6)], -1)
    normal = np.stack([np.zeros_like(xx), np.zeros_like(xx), -np.ones_like(xx)], -1)
    depth = (5.0 + yy / h)[..., None]
    footprint = 5.0 / w   # world units per pixel at depth 5 and a ~53 degree field of view
    position = np.stack([(xx + SYNTHETIC_PAN[0] * t) * footprint, (yy + SYNTHETIC_PAN[1] * t) * footprint,
                         depth[..., 0]], -1)
    color = albedo * rng.exponential(1.0, (h, w, 3)).astype(np.float32)
    motion = np.empty((h, w, 2), np.float32)
    motion[..., 0], motion[..., 1] = SYNTHETIC_PAN
    emissive = np.zeros((h, w, 1), np.float32)
    emissive[:h // 8, :w // 8] = 1.0      # a light in view, for the models that read the layer
    out = {"color": color.astype(np.float32), "albedo": albedo.astype(np.float32),
           "normal": normal, "depth": depth.astype(np.float32), "emissive": emissive,
           "position": position.astype(np.float32), "motion": motion, "meta": {}}
    if spp:
        out.update(synthetic_samples(out, spp, rng))
    return out


def synthetic_samples(frame: dict, spp: int, rng: np.random.Generator) -> dict:
    """``spp`` per-sample features (S, H, W, F) for a :func:`synthetic_frame` dict whose means
    are its pixel layers (radiance: albedo times exponential noise; a tenth of the samples hit
    specular material), the ``color`` they average to, and an identity camera (so screen and
    world normals differ by the documented axis flips)."""
    from mcdenoise.runtime.frames import SAMPLE_FEATURES, SAMPLE_GROUPS as g, pixel_means

    h, w, _ = frame["color"].shape
    samples = np.zeros((spp, h, w, len(SAMPLE_FEATURES)), np.float32)
    samples[..., g["radiance"]] = frame["albedo"] * rng.exponential(1.0, (spp, h, w, 3))
    for name in ("albedo", "normal", "depth", "emissive", "position"):
        samples[..., g[name]] = frame[name]
    samples[..., g["roughness"]] = 1.0
    samples[..., g["specular"]] = rng.random((spp, h, w, 1)) < 0.1
    return {"samples": samples, "color": pixel_means(samples)["color"],
            "meta": {**frame["meta"], "camera": {"to_world": np.eye(4).tolist()}}}


def onnx_driver(path: str, threads: int, device: str = "cpu"):
    """The runtime driver of ``path`` set up for timing (graph profiled on the CPU).

    On ``device="cuda"`` (onnxruntime's CUDA provider) the graph is not profiled: CUDA kernels
    run asynchronously, so per-node times would be launch times; the graph row is the run()
    call, which returns only when the outputs are back on the host."""
    from mcdenoise.runtime.denoiser import Denoiser
    from mcdenoise.training.methods import PROVIDERS

    den = Denoiser.load(path, threads=threads, providers=PROVIDERS[device], profile=device == "cpu",
                        log=lambda m: None)
    if device == "cuda" and den.session.get_providers()[0] != "CUDAExecutionProvider":
        raise ValueError(f"{path}: onnxruntime has no CUDA provider here (providers: "
                           f"{', '.join(den.session.get_providers())}); install onnxruntime-gpu")
    return den


def builtin_method(name: str, threads: int, device: str = "cpu"):
    """A built-in method (:func:`training.methods.load_method`) for timing; None for ``noisy``."""
    from mcdenoise.training.methods import load_method

    if name == "noisy":
        return None
    return oidn_cuda(name[len("oidn-"):]) if device == "cuda" and name.startswith("oidn-") else \
        load_method(name, threads=threads, device=device)


#: Pause before each timed call of :func:`time_interleaved`: onnxruntime's and Open Image
#: Denoise's worker threads spin for a while after a call, and would otherwise steal cores
#: from the next method.  (A longer pause also lets caches go cold and the vCPUs idle: with
#: 50 ms every method got slower, wskpn-3's numpy stages by about a quarter.)
SETTLE_S = 0.01


def time_interleaved(runners: dict, w: int, h: int, frames: int, warmup: int, seed: int = 0, spp: int = 0) -> dict:
    """Run every method of ``runners`` (name -> callable(frame)) on the synthetic sequence,
    interleaved frame by frame (frame t goes through every method before frame t + 1, the
    order rotating), so that a machine slowing down or speeding up mid-run affects every method
    alike and their ratios stay honest.  Returns name -> list of whole-call ms per frame
    (frames prepared outside the timed call; with ``spp`` per-sample data too)."""
    names = list(runners)
    ms: dict[str, list] = {n: [] for n in names}
    for t in range(warmup + frames):
        k = t % max(1, len(names))
        for n in names[k:] + names[:k]:
            fr = synthetic_frame(w, h, t, seed, spp)
            time.sleep(SETTLE_S)
            t0 = time.perf_counter()
            runners[n](fr)
            ms[n].append(1e3 * (time.perf_counter() - t0))
    return ms


def oidn_cuda(quality: str):
    """Open Image Denoise on its CUDA device (pyoidn runs it on torch CUDA tensors); the copies
    to and from the GPU are part of the cost, as they are for the onnxruntime driver."""
    import torch

    from mcdenoise.training.methods import OIDN

    class OIDNCuda(OIDN):
        def _array(self, a):
            return torch.from_numpy(a).cuda()

        def _numpy(self, out):
            return out.cpu().numpy().astype(np.float32, copy=False)

    return OIDNCuda(quality)


def bench_torch(model, protocol, contract_stages, w: int, h: int, frames: int, warmup: int, seed: int = 0,
                device: str = "cpu", spp: int = 4):
    """{stage: median ms} and the graph's total of torch eager, stages by forward hooks (on
    ``device="cuda"`` each hook synchronises, so a stage's time is its kernels' time).
    ``protocol`` (:class:`runtime.temporal.Protocol`) names the inputs a history fills."""
    import torch

    model = model.to(device)

    def now():
        if device == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter()

    from mcdenoise.runtime.contract import SAMPLES_INPUT
    from mcdenoise.runtime.frames import Frame
    from mcdenoise.runtime.inputs import frame_inputs, sample_inputs

    times: dict[str, list] = {}
    starts: dict[str, float] = {}
    handles = []
    for s in contract_stages:
        mod = getattr(model, s, None)
        if mod is None:
            continue
        handles.append(mod.register_forward_pre_hook(lambda m, a, s=s: starts.__setitem__(s, now())))
        handles.append(mod.register_forward_hook(
            lambda m, a, o, s=s: times.setdefault(s, []).append(1e3 * (now() - starts[s]))))
    def inputs(t):
        # A fresh frame per call, prepared outside the timed region, as the onnxruntime driver
        # gets one: timing one tensor set over and over would run torch from warm caches.
        groups = [g for g, _ in getattr(model, "sample_groups", ())]
        frame = Frame(**synthetic_frame(w, h, t, seed, spp if groups else 0))
        layers = [n for n in model.input_names if n not in protocol.inputs and n != SAMPLES_INPUT
                  and n not in getattr(model, "settings", {})]
        feeds = {k: torch.from_numpy(v).to(device) for k, v in frame_inputs(frame, layers).items()}
        if groups:
            feeds[SAMPLES_INPUT] = torch.from_numpy(sample_inputs(frame, groups)).to(device)
        feeds.update({k: torch.tensor(v) for k, v in getattr(model, "settings", {}).items()})
        # The protocol's own first-frame feeds (its fed state weights among them), then a
        # history in full swing: every pixel has one, the state holds colour-like values.
        protocol.start(feeds, torch.zeros(1, 1, h, w, device=device), spp if groups else None)
        for _, inp, _, ch in protocol.state:
            feeds[inp] = feeds["color"][:, :1].expand(-1, ch, -1, -1).clone()
        if protocol.state:
            feeds[protocol.history] = torch.ones(1, 1, h, w, device=device)
        return [feeds[n] for n in model.input_names]

    total = []
    with torch.inference_mode():
        for i in range(warmup + frames):
            args = inputs(i)
            t0 = now()
            model(*args)
            total.append(1e3 * (now() - t0))
    for hd in handles:
        hd.remove()
    med = {s: statistics.median(v[warmup:]) for s, v in times.items()}
    med[timing.GRAPH] = statistics.median(total[warmup:])
    return med


def gpu_name() -> str:
    """The CUDA device's name (torch), for tables written with ``--device cuda``."""
    try:
        import torch

        return torch.cuda.get_device_name(0)
    except Exception:  # a label only: never fail a benchmark over it
        return "CUDA GPU"
