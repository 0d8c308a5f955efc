"""``mcdenoise denoise --model FILE --input PATH --output DIR``: denoise a sequence, print timings.

``--input`` is a sequence folder of frame EXRs (our format), one frame EXR, or a plain colour
EXR/PFM with optional ``--albedo``/``--normal`` images (the Open Image Denoise convention)
and ``--depth`` (which the shipped models need too).
Writes ``<output>/<name>.exr`` (plain R,G,B linear HDR) per frame, PNG previews with ``--png``,
and prints the per-stage timing table (median over frames after the first) beside the paper's
numbers, plus PSNR against the frames' reference when they carry one.
"""
from __future__ import annotations

import json
import os
from pathlib import Path


from mcdenoise.runtime import data_path, timing
from mcdenoise.runtime.args import add_threads
from mcdenoise.runtime.denoiser import Denoiser
from mcdenoise.runtime.frames import FrameError, frame_paths, read_frame, read_plain
from mcdenoise.runtime.writers import write_png, write_rgb
from mcdenoise.training.metrics import pixels, psnr
from mcdenoise.runtime.transfer import gamma

DEFAULT_MODEL = data_path("models", "wskpn-3.onnx")
SAMPLE_SEQUENCE = data_path("samples", "sequence")


def add_arguments(p):
    p.add_argument("--model", default=str(DEFAULT_MODEL), help="ONNX model (default: the shipped models/wskpn-3.onnx)")
    p.add_argument("--input", default=str(SAMPLE_SEQUENCE),
                   help="sequence folder, frame EXR, or plain colour EXR/PFM (default: the shipped sample sequence)")
    p.add_argument("--albedo", default=None, help="albedo image for a plain colour input")
    p.add_argument("--normal", default=None, help="normal image for a plain colour input")
    p.add_argument("--depth", default=None,
                   help="depth image for a plain colour input (one channel: Z, Y or a grey RGB EXR, or a Pf PFM; any unit)")
    p.add_argument("--emissive", default=None,
                   help="emissive image for a plain colour input, for models that read it (wskpn-6e): the fraction "
                        "of each pixel's samples whose first hit is a light, in [0, 1] (one channel, as --depth)")
    p.add_argument("--output", required=True, metavar="DIR", help="folder for denoised EXRs")
    p.add_argument("--png", action="store_true", help="also write tonemapped PNG previews")
    p.add_argument("--no-profile", action="store_true",
                   help="skip onnxruntime profiling (graph time is then one row)")
    p.add_argument("--json", default=None, help="also write per-frame timings and metrics as JSON here")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="cuda: onnxruntime's CUDA provider (needs onnxruntime-gpu; the graph is then "
                        "one row: CUDA kernels run asynchronously)")
    p.add_argument("--no-autoexposure", action="store_true",
                   help="feed the colour in the renderer's units (see README, auto-exposure)")
    add_threads(p)


def load_inputs(path: str, albedo: str | None = None, normal: str | None = None, depth: str | None = None,
                emissive: str | None = None):
    """Sequences in the input: a list of (sequence name, [(frame name, loader), ...]).

    A folder of frames is one sequence; a folder of sequence folders (what ``mcdenoise
    render`` writes) is several.  Loaders read lazily so long sequences stream."""
    if os.path.isdir(path):
        paths = frame_paths(path)
        if paths:
            return [("", [(Path(p).stem, (lambda p=p: read_frame(p, samples=False))) for p in paths])]
        seqs = []
        for sub in sorted(Path(path).iterdir()):
            if sub.is_dir() and frame_paths(sub):
                seqs.append((sub.name, [(Path(p).stem, (lambda p=p: read_frame(p, samples=False)))
                                        for p in frame_paths(sub)]))
        if not seqs:
            raise FrameError(f"{path}: no frame_*.exr frames in this folder or its sub-folders")
        return seqs
    if not os.path.exists(path):
        raise FrameError(f"{path}: no such file or folder")
    if albedo or normal or depth or emissive or path.lower().endswith(".pfm"):
        return [("", [(Path(path).stem, lambda: read_plain(path, albedo, normal, depth, emissive))])]
    try:
        read_frame(path, layers=["color"], samples=False)
        return [("", [(Path(path).stem, lambda: read_frame(path, samples=False))])]
    except FrameError:
        return [("", [(Path(path).stem, lambda: read_plain(path))])]


def run(model: str, input_path: str, output: str, png: bool = False, profile: bool = True,
        threads: int = 0, albedo=None, normal=None, log=print, device: str = "cpu", depth=None,
        autoexposure: bool = True, emissive=None) -> dict:
    from mcdenoise.training.methods import PROVIDERS

    den = Denoiser.load(model, threads=threads, profile=profile and device == "cpu",
                        providers=PROVIDERS[device], autoexposure=autoexposure)
    if device == "cuda" and den.session.get_providers()[0] != "CUDAExecutionProvider":
        raise ValueError(f"{model}: onnxruntime has no CUDA provider here (providers: "
                         f"{', '.join(den.session.get_providers())}); install onnxruntime-gpu")
    seqs = load_inputs(input_path, albedo, normal, depth, emissive)
    outs, refs = [], []
    n_frames = 0
    for seq_name, items in seqs:
        den.reset()
        out_dir = Path(output) / seq_name
        out_dir.mkdir(parents=True, exist_ok=True)
        for name, load in items:
            frame = load()
            missing = [l for l in den.frame_layers if getattr(frame, l, None) is None]
            if missing and frame.meta.get("source") == "plain":
                raise FrameError(f"{frame.path}: model {den.contract.spec_name} needs {', '.join(missing)} "
                                 f"beside the colour: give " + " ".join(f"--{l} FILE" for l in missing))
            image = den(frame)
            n_frames += 1
            write_rgb(out_dir / f"{name}.exr", image, meta={"model": den.contract.spec_name, "source": frame.path})
            if png:
                write_png(out_dir / f"{name}.png", gamma(image))
            if frame.reference is not None:
                outs.append(image)
                refs.append(frame.reference)
    skip = 1 if n_frames > 1 else 0
    log(den.stage_table(skip=skip))
    rows = den.stage_times()
    timed, size, _ = den.timed_frames(skip)
    result = {"model": den.contract.spec_name, "frames": n_frames, "sequences": len(seqs),
              "sanitized_frames": den.report.sanitized_frames, "resets": den.report.resets,
              "stage_ms_median": timing.medians(timed), "stage_median_size": list(size[::-1]) if size else None,
              "stage_ms_per_frame": rows, "frame_sizes": [[w, h] for h, w in den.frame_sizes]}
    if refs:
        # Over all pixels of all frames (ANF Eq. 14's sequence PSNR), whatever their sizes:
        # a sequence may change resolution, or a folder hold sequences of several.
        result["psnr_db"] = psnr(pixels(outs), pixels(refs))
        log(f"PSNR vs reference over {len(refs)} frames: {result['psnr_db']:.2f} dB (ANF Eq. 14)")
    log(f"wrote {n_frames} frame(s) of {len(seqs)} sequence(s) to {output}")
    return result


def main(args) -> int:
    result = run(args.model, args.input, args.output, png=args.png, profile=not args.no_profile,
                 threads=args.threads, albedo=args.albedo, normal=args.normal, depth=args.depth,
                 emissive=args.emissive,
                 device=args.device,
                 autoexposure=not args.no_autoexposure)
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2, default=float) + "\n")
    return 0
