"""``mcdenoise stress [METHOD...]``: how much each denoising method degrades on hard input.

For every method (:func:`runtime.methods.load_method`: shipped ONNX models through the runtime
driver, Open Image Denoise, SVGF, the noisy input) and every *case*, the case is scored against
its *clean counterpart* and the error increase is reported, with a PNG crop of the worst region.

Cases made by perturbing clean frames of the data set (no rendering; pixel layers recomputed
from the perturbed per-sample data with :func:`runtime.frames.pixel_means`):

* ``fireflies``: about one sample in :data:`FIREFLY_DENSITY` pixels gets radiance
  :data:`FIREFLY_FACTOR` x the mean of the clean image (ANF Fig. 3 adds "a value up to 500x
  the mean of the image"; we use the top of that range);
* ``nan-inf``: as many samples per kind get NaN radiance, +Inf radiance, or NaN in every
  feature (then the pixel's motion vector is NaN as well);
* ``cut``: the data set's sequences played back to back as one stream, each start flagged
  ``meta["cut"]``; ``cut-unflagged``: the same without the flag and with the ``valid`` layer
  set to 1 on the frame after the cut (its motion vectors are 0), so only a method's own
  history test can notice (both scored on the frames after the first cut);
* ``dark`` / ``bright``: colour, per-sample radiance and reference times :data:`EXPOSURES`;
  scored after dividing the output (and reference) by the same factor, so a method that
  scales with its input loses nothing;
* ``1spp``: the first sample only, against the ``--spp`` clean case.

Cases from rendered sets (``mcdenoise render``, held-out scene seeds ``RENDER_SEED`` * 100000
+ i, cached under ``--render-dir``; same scenes as the ``base`` set, only the effect changes):

* ``disocclusion``: the camera moves :data:`FAST_CAMERA` x as fast (vs ``base``);
* ``defocus``: a thin lens with :data:`APERTURE_SCALE` x the generator's aperture (vs ``base``);
* ``motion-blur``: camera motion blur at the fast camera speed (vs ``disocclusion``'s set, the
  same camera path without blur);
* ``glossy``: the floor is glossy silver (GGX alpha 0.05): large reflections whose motion
  vectors (which follow the first hit) are wrong (vs ``base``).

Scores: PSNR (ANF Eq. 14) and relMSE (:mod:`runtime.metrics`) over all scored frames of a case,
with non-finite output values counted and set to 0 before scoring.  The failure rule is
:func:`judge`.  Outputs: ``stress.md``, ``stress.csv`` and ``stress/<case>.png`` in ``--out``.
"""
from __future__ import annotations

import csv
import json
import math
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from runtime.frames import Frame, FrameError, pixel_means, read_frame, SAMPLE_GROUPS, write_png
from runtime.metrics import psnr, relmse
from runtime.transfer import reinhard_gamma

REPO = Path(__file__).resolve().parent.parent
#: ANF Fig. 3: outlier samples "up to 500x the mean of the image".
FIREFLY_FACTOR = 500.0
#: Perturbed samples per pixel (per kind for ``nan-inf``): 16 per 128x128 frame.
FIREFLY_DENSITY = 1e-3
NONFINITE_DENSITY = 1e-3
#: Exposure cases: factor applied to colour, samples and reference.
EXPOSURES = {"dark": 1e-3, "bright": 1e3}
#: A method fails a case when it loses this many dB more than the noisy input does (see judge).
FAIL_MARGIN_DB = 3.0
#: stress.md lists losses of more than this many dB beyond the noisy input's that are not failures.
NOTE_MARGIN_DB = 1.0
#: Scene seeds of the rendered stress sets: RENDER_SEED * 100000 + i (training uses 1, test 2).
RENDER_SEED = 5
FAST_CAMERA = 4.0
APERTURE_SCALE = 6.0
#: Methods run by default besides the shipped ONNX models.
DEFAULT_EXTRA = ("oidn-high", "svgf", "noisy")

#: Rendered sets: name -> (render flags, what it is).
RENDER_SETS: dict[str, tuple[tuple[str, ...], str]] = {
    "base": (("--defocus", "off"), "pinhole, camera speed 1"),
    "fast": (("--defocus", "off", "--camera-speed", f"{FAST_CAMERA:g}"), f"camera speed {FAST_CAMERA:g}"),
    "defocus": (("--defocus", "on", "--aperture-scale", f"{APERTURE_SCALE:g}"),
                f"thin lens, aperture x{APERTURE_SCALE:g}"),
    "motion-blur": (("--defocus", "off", "--camera-speed", f"{FAST_CAMERA:g}", "--motion-blur", "on"),
                    f"camera motion blur, camera speed {FAST_CAMERA:g}"),
    "glossy": (("--defocus", "off", "--floor", "glossy"), "glossy silver floor"),
}
#: Size of the rendered sets: full run and --quick.
FULL_RENDER = {"scenes": 3, "frames": 4, "size": "128x128", "spp": 4, "ref_spp": 256}
QUICK_RENDER = {"scenes": 2, "frames": 2, "size": "64x64", "spp": 4, "ref_spp": 32}
#: --quick keeps this many sequences x frames of the data set.
QUICK_LIMIT = (2, 2)


# ----------------------------------------------------------------------------------------------
# Perturbations (pure functions of a frame with per-sample data and a random generator)
# ----------------------------------------------------------------------------------------------

def with_samples(frame: Frame, samples: np.ndarray) -> Frame:
    """``frame`` with per-sample data ``samples`` (S, H, W, F) and its pixel layers recomputed
    from them (:func:`runtime.frames.pixel_means`); motion, valid, reference and meta kept."""
    px = pixel_means(samples)
    return Frame(color=px["color"], albedo=px["albedo"], normal=px["normal"], depth=px["depth"],
                 position=px["position"], motion=None if frame.motion is None else frame.motion.copy(),
                 valid=frame.valid, reference=frame.reference, samples=samples,
                 meta=dict(frame.meta, spp=int(samples.shape[0])), path=frame.path)


def at_spp(frame: Frame, n: int) -> Frame:
    """The frame as if rendered with its first ``n`` stored samples (per-sample data kept)."""
    if frame.samples is None:
        raise FrameError(f"{frame.path}: no per-sample layers (stress needs them)")
    if n > frame.spp:
        raise FrameError(f"{frame.path}: holds {frame.spp} samples per pixel, {n} requested")
    return with_samples(frame, frame.samples[:n].copy())


def _pick(rng: np.random.Generator, frame: Frame, density: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sample index, y, x) arrays of max(1, round(density * H * W)) distinct pixels."""
    h, w = frame.size
    n = max(1, int(round(density * h * w)))
    flat = rng.choice(h * w, size=min(n, h * w), replace=False)
    return rng.integers(0, frame.spp, size=len(flat)), flat // w, flat % w


def inject_fireflies(frame: Frame, rng: np.random.Generator, factor: float = FIREFLY_FACTOR,
                     density: float = FIREFLY_DENSITY) -> tuple[Frame, np.ndarray]:
    """Outlier samples: about ``density`` per pixel get radiance ``factor`` x the mean of the
    frame's clean colour (all pixels and channels), in every channel.  Returns the new frame
    and the (n, 3) array of (sample, y, x) changed."""
    s, y, x = _pick(rng, frame, density)
    value = factor * float(np.mean(frame.color, dtype=np.float64))
    samples = frame.samples.copy()
    samples[s, y, x, SAMPLE_GROUPS["radiance"]] = value
    return with_samples(frame, samples), np.stack([s, y, x], 1)


def inject_nonfinite(frame: Frame, rng: np.random.Generator,
                     density: float = NONFINITE_DENSITY) -> tuple[Frame, dict]:
    """Broken samples, about ``density`` per pixel of each kind: NaN radiance, +Inf radiance,
    and NaN in every feature (whose pixels also get a NaN motion vector, as a renderer averaging
    its samples' motion would give).  Returns the frame and {kind: (n, 3) (sample, y, x)}."""
    samples = frame.samples.copy()
    where: dict[str, np.ndarray] = {}
    h, w = frame.size
    n = max(1, int(round(density * h * w)))
    flat = rng.choice(h * w, size=min(3 * n, h * w), replace=False)
    parts = np.array_split(flat, 3)
    rad = SAMPLE_GROUPS["radiance"]
    motion = None if frame.motion is None else frame.motion.copy()
    for kind, idx in zip(("nan-radiance", "inf-radiance", "nan-sample"), parts):
        s, y, x = rng.integers(0, frame.spp, size=len(idx)), idx // w, idx % w
        if kind == "nan-radiance":
            samples[s, y, x, rad] = np.nan
        elif kind == "inf-radiance":
            samples[s, y, x, rad] = np.inf
        else:
            samples[s, y, x, :] = np.nan
            if motion is not None:
                motion[y, x] = np.nan
        where[kind] = np.stack([s, y, x], 1)
    out = with_samples(frame, samples)
    out.motion = motion
    return out, where


def exposed(frame: Frame, k: float) -> Frame:
    """The frame at exposure ``k``: colour, per-sample radiance and reference times k."""
    samples = None
    if frame.samples is not None:
        samples = frame.samples.copy()
        samples[..., SAMPLE_GROUPS["radiance"]] *= np.float32(k)
    return replace(frame, color=frame.color * np.float32(k), samples=samples,
                   reference=None if frame.reference is None else frame.reference * np.float32(k),
                   meta=dict(frame.meta, exposure=k))


# ----------------------------------------------------------------------------------------------
# Runs and cases
# ----------------------------------------------------------------------------------------------

@dataclass
class Run:
    """Frames fed to every method: ``sequences`` (a reset before each), and per frame a key
    (source sequence, frame) when the frame is scored, else None.  ``scale`` multiplies outputs
    and references before scoring (undoes an exposure change)."""

    name: str
    sequences: list
    keys: list
    scale: float = 1.0

    def frames(self):
        for seq, keys in zip(self.sequences, self.keys):
            for fr, k in zip(seq, keys):
                yield fr, k


@dataclass
class Case:
    """A stress case: ``run`` scored against ``clean`` on the keys ``run`` scores; ``aligned``
    when the two show the same pixels (perturbation cases), so a per-pixel error increase exists."""

    name: str
    what: str
    run: str
    clean: str
    aligned: bool
    skipped: str | None = None
    vs: str | None = None  # the counterpart's set name when the run is shared ("base" is "clean")


def _keys(seqs):
    """Every frame scored, keyed (sequence, frame)."""
    return [[(i, t) for t in range(len(s))] for i, s in enumerate(seqs)]


def load_set(root: str, limit: tuple[int, int] | None = None) -> list[list[Frame]]:
    """Frames of every sequence under ``root`` (at most ``limit`` = (sequences, frames))."""
    from training.evaluate import sequences

    seqs = sequences(root)
    if limit:
        seqs = [s[:limit[1]] for s in seqs[:limit[0]]]
    return [[read_frame(p) for p in s] for s in seqs]


def _strip(seqs):
    """Drop per-sample data (methods see pixel layers) to keep memory small."""
    for s in seqs:
        for fr in s:
            fr.samples = None
    return seqs


def perturbation_runs(data: list[list[Frame]], spp: int, seed: int) -> tuple[dict, list[Case]]:
    """The runs and cases made from the data set's frames (see the module docstring).  The
    runs' frames carry no per-sample data (dropped once the pixel layers are made)."""
    clean = [[at_spp(f, spp) for f in s] for s in data]
    runs: dict[str, Run] = {}
    cases = []

    def add(name: str, seqs, keys=None, scale: float = 1.0) -> None:
        runs[name] = Run(name, _strip(seqs), keys or _keys(seqs), scale)

    def rng(case_id: int, i: int, t: int):
        return np.random.default_rng([seed, case_id, i, t])

    add("fireflies", [[inject_fireflies(f, rng(1, i, t))[0] for t, f in enumerate(s)] for i, s in enumerate(clean)])
    cases.append(Case("fireflies", f"{FIREFLY_DENSITY * 1e3:g} sample per 1000 pixels at "
                      f"{FIREFLY_FACTOR:g}x the image mean (ANF Fig. 3)", "fireflies", "clean", True))
    add("nan-inf", [[inject_nonfinite(f, rng(2, i, t))[0] for t, f in enumerate(s)] for i, s in enumerate(clean)])
    cases.append(Case("nan-inf", f"{NONFINITE_DENSITY * 1e3:g} sample per 1000 pixels each with NaN "
                      "radiance, +Inf radiance, NaN in every feature", "nan-inf", "clean", True))
    one = [[at_spp(f, 1) for f in s] for s in data]
    _strip(clean)
    if len(clean) >= 2:
        for name, flagged in (("cut", True), ("cut-unflagged", False)):
            stream = [replace(f, meta=dict(f.meta, cut=flagged and t == 0),
                              valid=f.valid if flagged or t > 0 or f.valid is None else np.ones_like(f.valid))
                      for s in clean for t, f in enumerate(s)]
            keys = [[(i, t) if i > 0 else None for i, s in enumerate(clean) for t in range(len(s))]]
            add(name, [stream], keys)
            cases.append(Case(name, "sequences back to back as one stream, the first frame after each cut "
                              + ("flagged `meta['cut']`" if flagged else "NOT flagged: motion vectors 0, `valid` 1 (only a history test can tell)"),
                              name, "clean", True))
    else:
        for name in ("cut", "cut-unflagged"):
            cases.append(Case(name, "sequences back to back", name, "clean", True,
                              skipped="the data set has one sequence"))
    for name, k in EXPOSURES.items():
        add(name, [[exposed(f, k) for f in s] for s in clean], scale=1.0 / k)
        cases.append(Case(name, f"colour, samples and reference x{k:g}; scored after dividing by {k:g}",
                          name, "clean", True))
    add("1spp", one)
    cases.append(Case("1spp", f"1 sample per pixel (clean case: {spp} spp)", "1spp", "clean", True))
    add("clean", clean)
    return runs, cases


RENDERED_CASES = (  # case, set, clean counterpart set, description
    ("disocclusion", "fast", "base", f"camera {FAST_CAMERA:g}x faster: disocclusions, long motion vectors"),
    ("defocus", "defocus", "base", f"thin lens, aperture x{APERTURE_SCALE:g} (strong defocus)"),
    ("motion-blur", "motion-blur", "fast", f"camera motion blur at camera speed {FAST_CAMERA:g}"),
    ("glossy", "glossy", "base", "glossy silver floor: reflections move unlike their motion vectors"),
)


# ----------------------------------------------------------------------------------------------
# Rendering the stress sets
# ----------------------------------------------------------------------------------------------

def render_args(name: str, quick: bool) -> list[str]:
    """``mcdenoise render`` arguments (without --out) of a stress set."""
    cfg = QUICK_RENDER if quick else FULL_RENDER
    return ["--scenes", str(cfg["scenes"]), "--frames", str(cfg["frames"]), "--size", cfg["size"],
            "--spp", str(cfg["spp"]), "--ref-spp", str(cfg["ref_spp"]), "--seed", str(RENDER_SEED),
            "--workers", "1", *RENDER_SETS[name][0]]


def _set_complete(folder: Path, name: str, quick: bool) -> bool:
    """The folder's manifest says it holds this set (same settings, every sequence): reuse it."""
    from runtime.frames import MANIFEST

    try:
        man = json.loads((folder / MANIFEST).read_text())
    except (OSError, json.JSONDecodeError):
        return False
    cfg = QUICK_RENDER if quick else FULL_RENDER
    flags = RENDER_SETS[name][0]
    want = {"spp": cfg["spp"], "ref_spp": cfg["ref_spp"], "seed": RENDER_SEED, "scenes": cfg["scenes"],
            "frames": cfg["frames"], "size": [int(v) for v in cfg["size"].split("x")],
            "camera_speed": float(flags[flags.index("--camera-speed") + 1]) if "--camera-speed" in flags else 1.0,
            "defocus_probability": 1.0 if flags[flags.index("--defocus") + 1] == "on" else 0.0,
            "motion_blur_probability": 1.0 if "--motion-blur" in flags else 0.0,
            "aperture_scale": float(flags[flags.index("--aperture-scale") + 1]) if "--aperture-scale" in flags else None,
            "floor": flags[flags.index("--floor") + 1] if "--floor" in flags else None}
    got = man.get("settings", {})
    if any(got.get(k) != v for k, v in want.items()):
        return False
    seqs = man.get("sequences", [])
    return len(seqs) == cfg["scenes"] and all(
        len(list((folder / e["folder"]).glob("frame_*.exr"))) == cfg["frames"] for e in seqs)


def ensure_set(render_dir: str, name: str, quick: bool, render: bool = True, log=print) -> tuple[str | None, dict]:
    """Folder of stress set ``name`` (rendered by ``mcdenoise render`` in a subprocess if missing,
    unless ``render`` is False: then None).  Returns (folder, info: command, render seconds)."""
    folder = Path(render_dir) / (("quick-" if quick else "") + name)
    args = render_args(name, quick)
    info = {"command": "mcdenoise render --out " + str(folder) + " " + " ".join(args)}
    if not _set_complete(folder, name, quick):
        if not render:
            return None, info
        cmd = [sys.executable, "-m", "runtime.cli", "render", "--out", str(folder), *args]
        log(f"stress: rendering set {name!r}: {info['command']}")
        start = time.perf_counter()
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
        if proc.returncode != 0:
            tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
            raise RuntimeError(f"rendering stress set {name!r} failed: {tail}")
        info["wall_seconds"] = round(time.perf_counter() - start, 1)
    from runtime.frames import MANIFEST

    man = json.loads((folder / MANIFEST).read_text())
    secs = [e.get("render_seconds", 0.0) for e in man.get("sequences", [])]
    frames = sum(e.get("frames", 0) for e in man.get("sequences", []))
    info.update(render_seconds=round(sum(secs), 1), frames=frames,
                seconds_per_frame=round(sum(secs) / max(frames, 1), 2),
                seeds=[e.get("scene_seed") for e in man.get("sequences", [])],
                variant=(man.get("settings") or {}).get("variant"))
    return str(folder), info


# ----------------------------------------------------------------------------------------------
# Running and scoring
# ----------------------------------------------------------------------------------------------

@dataclass
class Result:
    """One method on one run: outputs of the scored frames by key, non-finite output values
    (all frames), the error message if it raised, driver state resets."""

    outputs: dict = field(default_factory=dict)
    nonfinite: int = 0
    error: str | None = None
    resets: int | None = None


def _fresh(fr: Frame) -> Frame:
    """A copy a method may modify without touching the next method's input."""
    arrays = {k: (None if getattr(fr, k) is None else getattr(fr, k).copy())
              for k in ("color", "albedo", "normal", "depth", "position", "motion", "valid", "reference")}
    return Frame(**arrays, samples=None, meta=json.loads(json.dumps(fr.meta)), path=fr.path)


def run_method(method, run: Run) -> Result:
    """Feed ``run`` to ``method`` (reset before each sequence); never raises."""
    res = Result()
    den = getattr(method, "denoiser", None)
    before = len(den.report.resets) if den is not None else None
    try:
        for seq, keys in zip(run.sequences, run.keys):
            method.reset()
            for fr, key in zip(seq, keys):
                out = np.asarray(method(_fresh(fr)), dtype=np.float32)
                if out.shape != fr.color.shape:
                    raise ValueError(f"output shape {out.shape}, expected {fr.color.shape}")
                res.nonfinite += int((~np.isfinite(out)).sum())
                if key is not None:
                    res.outputs[key] = out
    except Exception as e:  # a method that raises fails the case; the suite goes on
        msg = " ".join(str(e).split()) or type(e).__name__
        res.error = f"{type(e).__name__}: {msg[:200]}"
    if den is not None:
        res.resets = len(den.report.resets) - before
    return res


def _refs(run: Run) -> dict:
    return {k: fr.reference for fr, k in run.frames() if k is not None}


def _inputs(run: Run) -> dict:
    return {k: fr.color for fr, k in run.frames() if k is not None}


def score(outputs: dict, refs: dict, keys: list, scale: float = 1.0) -> dict:
    """PSNR (ANF Eq. 14) and relMSE over the frames ``keys``; non-finite output -> 0 first."""
    o = np.stack([np.nan_to_num(outputs[k], nan=0.0, posinf=0.0, neginf=0.0) for k in keys]).astype(np.float64) * scale
    r = np.stack([refs[k] for k in keys]).astype(np.float64) * scale
    return {"psnr": psnr(o, r), "relmse": relmse(o, r)}


def judge(method: str, row: dict, noisy: dict | None) -> str | None:
    """Why ``method`` fails a case, or None.  The rule (stated once, in stress.md too): a method
    fails when it raised, when any output value is non-finite, when its PSNR on the case is
    below the noisy input's, or when it loses more than FAIL_MARGIN_DB dB more than the noisy
    input loses against the clean counterpart.  The noisy input is the yardstick, never judged."""
    if method == "noisy":
        return None
    if row.get("error"):
        return "crashed"
    if row["nonfinite"]:
        return f"non-finite output ({row['nonfinite']} values)"
    if noisy is None or noisy.get("error") or noisy.get("psnr_case") is None:
        return None
    if row["psnr_case"] < noisy["psnr_case"]:
        return f"worse than the noisy input ({row['psnr_case']:.2f} < {noisy['psnr_case']:.2f} dB)"
    beyond = row["delta_db"] - noisy["delta_db"]
    if beyond < -FAIL_MARGIN_DB:
        return f"loses {-beyond:.1f} dB more than the noisy input"
    return None


# ----------------------------------------------------------------------------------------------
# Crops
# ----------------------------------------------------------------------------------------------

def error_map(out: np.ndarray, ref: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Per-pixel squared error of tonemapped radiance (ANF Eq. 15), mean over channels (H, W)."""
    o = np.nan_to_num(out.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0) * scale
    d = reinhard_gamma(o) - reinhard_gamma(ref.astype(np.float64) * scale)
    return (d * d).mean(axis=-1)


def worst_window(maps: dict, size: int) -> tuple:
    """(key, y, x) of the size x size window with the largest sum over ``maps`` {key: (H, W)}."""
    best = (-math.inf, None, 0, 0)
    for k, m in maps.items():
        h, w = m.shape
        s = min(size, h, w)
        c = np.zeros((h + 1, w + 1))
        c[1:, 1:] = m.cumsum(0).cumsum(1)
        win = c[s:, s:] - c[:-s, s:] - c[s:, :-s] + c[:-s, :-s]
        y, x = np.unravel_index(int(np.argmax(win)), win.shape)
        if win[y, x] > best[0]:
            best = (float(win[y, x]), k, int(y), int(x))
    return best[1], best[2], best[3]


def _display(img: np.ndarray | None, scale: float, shape) -> np.ndarray:
    """Tonemapped [0, 1] panel; non-finite pixels magenta, a missing output grey."""
    if img is None:
        return np.full(shape, 0.5)
    img = img.astype(np.float64) * scale
    bad = ~np.isfinite(img).all(axis=-1)
    out = reinhard_gamma(np.nan_to_num(img, nan=0.0, posinf=0.0, neginf=0.0))
    out[bad] = (1.0, 0.0, 1.0)
    return out


def compose(rows: list[tuple[str, list]], labels: list[str], path: str, zoom: int) -> None:
    """Write a PNG grid: one row per (row label, [panel (h, w, 3) in [0, 1]]), columns labelled.
    Panels are enlarged ``zoom`` x (nearest).  Labels need matplotlib; without it, none."""
    ph, pw = rows[0][1][0].shape[:2]
    ph, pw = ph * zoom, pw * zoom
    gap, top, left = 2, 14, 72
    width = left + len(labels) * (pw + gap)
    height = top + len(rows) * (ph + gap)
    canvas = np.ones((height, width, 3))
    for r, (_, panels) in enumerate(rows):
        for c, p in enumerate(panels):
            y, x = top + r * (ph + gap), left + c * (pw + gap)
            canvas[y:y + ph, x:x + pw] = np.repeat(np.repeat(p, zoom, 0), zoom, 1)
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        write_png(path, canvas)
        return
    fig = Figure(figsize=(width / 100, height / 100), dpi=100)
    FigureCanvasAgg(fig)
    fig.figimage(canvas, 0, 0, origin="upper")
    for c, lab in enumerate(labels):
        fig.text((left + c * (pw + gap) + pw / 2) / width, 1 - 2 / height, lab, ha="center", va="top", fontsize=7)
    for r, (lab, _) in enumerate(rows):
        fig.text(2 / width, 1 - (top + r * (ph + gap) + ph / 2) / height, lab, ha="left", va="center", fontsize=7)
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    write_png(path, img.astype(np.float64) / 255.0)


def crop_case(case: Case, runs: dict, results: dict, table: dict, methods: list[str], path: str,
              size: int, zoom: int) -> dict | None:
    """PNG of the worst region of ``case``: the window where the most degraded judged method
    (lowest PSNR change beyond the noisy input's) has the largest error increase over its clean
    output (aligned cases) or the largest error (rendered cases).  Columns: input, each
    method, reference; a second row shows the clean counterpart when aligned."""
    run, clean = runs[case.run], runs[case.clean]
    rows_ok = {m: table[(case.name, m)] for m in methods if (case.name, m) in table}
    judged = [m for m, r in rows_ok.items() if m != "noisy" and not r.get("error") and r.get("delta_db") is not None]
    if not judged:
        judged = [m for m, r in rows_ok.items() if not r.get("error") and r.get("delta_db") is not None]
    if not judged:
        return None
    nd = rows_ok.get("noisy", {}).get("delta_db") or 0.0
    worst = min(judged, key=lambda m: rows_ok[m]["delta_db"] - nd)
    refs, crefs = _refs(run), _refs(clean)
    keys = sorted(results[(case.run, worst)].outputs)
    maps = {}
    for k in keys:
        e = error_map(results[(case.run, worst)].outputs[k], refs[k], run.scale)
        if case.aligned:
            e = e - error_map(results[(case.clean, worst)].outputs[k], crefs[k], clean.scale)
        maps[k] = e
    key, y, x = worst_window(maps, size)
    h, w = refs[key].shape[:2]
    s = min(size, h, w)
    sl = (slice(y, y + s), slice(x, x + s))

    def row(r: Run, res_run: str) -> list:
        panels = [_display(_inputs(r)[key][sl], r.scale, (s, s, 3))]
        for m in methods:
            res = results.get((res_run, m))
            out = None if res is None or res.error else res.outputs.get(key)
            panels.append(_display(None if out is None else out[sl], r.scale, (s, s, 3)))
        panels.append(_display(_refs(r)[key][sl], r.scale, (s, s, 3)))
        return panels

    rows = [(case.name, row(run, case.run))]
    if case.aligned:
        rows.append(("clean", row(clean, case.clean)))
    compose(rows, ["input", *methods, "reference"], path, zoom)
    return {"method": worst, "frame": list(key), "y": y, "x": x, "size": s}


# ----------------------------------------------------------------------------------------------
# The suite
# ----------------------------------------------------------------------------------------------

def default_methods() -> list[str]:
    from runtime.methods import shipped_models

    return [*shipped_models(), *DEFAULT_EXTRA]


def stress(methods: list[str] | None = None, data: str | None = None, render_dir: str = "data/stress",
           out: str = "docs/results", quick: bool = False, spp: int = 4, render: bool = True,
           threads: int = 0, seed: int = 0, command: str | None = None, log=print) -> dict:
    """Run the suite and write ``stress.md``, ``stress.csv`` and ``stress/<case>.png`` into
    ``out``.  Returns {"table": {(case, method): row}, "cases": [...], "methods": [...], ...}."""
    from runtime.methods import load_method

    methods = list(methods) if methods else default_methods()
    started = time.perf_counter()
    sets: dict[str, dict] = {}
    limit = QUICK_LIMIT if quick else None
    if data is None:
        folder, info = ensure_set(render_dir, "base", quick, render, log)
        if folder is None:
            raise FrameError(f"no --data and the base stress set is not rendered in {render_dir} (--no-render)")
        sets["base"] = {**info, "folder": folder}
        data = folder
    data_seqs = load_set(data, limit=limit)
    runs, cases = perturbation_runs(data_seqs, spp, seed)
    del data_seqs
    # rendered sets; the base set is the clean run when it is the data set
    alias = {"base": "clean"} if "base" in sets else {}
    for case_name, set_name, clean_name, what in RENDERED_CASES:
        missing = False
        for name in (set_name, clean_name):
            if alias.get(name, name) in runs:
                continue
            folder, info = ensure_set(render_dir, name, quick, render, log)
            sets[name] = {**info, "folder": folder}
            if folder is None:
                missing = True
                continue
            seqs = _strip([[at_spp(f, spp) for f in s] for s in load_set(folder, limit=limit)])
            runs[name] = Run(name, seqs, _keys(seqs))
        cases.append(Case(case_name, what, alias.get(set_name, set_name), alias.get(clean_name, clean_name),
                          False, skipped=f"set not rendered in {render_dir} (--no-render)" if missing else None,
                          vs=clean_name))

    # methods
    loaded, names = {}, []
    load_errors = {}
    for m in methods:
        try:
            obj = load_method(m, threads=threads)
            name = obj.name
        except Exception as e:  # e.g. svgf not there, pyoidn not installed
            obj, name = None, (Path(m).stem if m.endswith(".onnx") else m)
            load_errors[name] = f"could not load: {type(e).__name__}: {' '.join(str(e).split())[:160]}"
        names.append(name)
        loaded[name] = obj
    results: dict = {}
    needed = sorted({c.run for c in cases if not c.skipped} | {c.clean for c in cases if not c.skipped} | {"clean"})
    for rname in needed:
        for name in names:
            if loaded[name] is None:
                results[(rname, name)] = Result(error=load_errors[name])
                continue
            results[(rname, name)] = run_method(loaded[name], runs[rname])
        log(f"stress: ran {rname}")

    # scoring
    table: dict = {}
    for case in cases:
        if case.skipped:
            for name in names:
                table[(case.name, name)] = {"skipped": case.skipped}
            continue
        run, clean = runs[case.run], runs[case.clean]
        keys = [k for _, k in run.frames() if k is not None]
        refs, crefs = _refs(run), _refs(clean)
        for name in names:
            res, cres = results[(case.run, name)], results[(case.clean, name)]
            row = {"nonfinite": res.nonfinite, "error": res.error or cres.error, "resets": res.resets,
                   "psnr_case": None, "psnr_clean": None, "delta_db": None,
                   "relmse_case": None, "relmse_clean": None}
            if not row["error"]:
                a = score(res.outputs, refs, keys, run.scale)
                b = score(cres.outputs, crefs, keys, clean.scale)
                row.update(psnr_case=a["psnr"], psnr_clean=b["psnr"], delta_db=a["psnr"] - b["psnr"],
                           relmse_case=a["relmse"], relmse_clean=b["relmse"])
            table[(case.name, name)] = row
        noisy = table.get((case.name, "noisy"))
        for name in names:
            table[(case.name, name)]["failed"] = judge(name, table[(case.name, name)], noisy)
    clean_rows = {}
    keys = [k for _, k in runs["clean"].frames() if k is not None]
    for name in names:
        res = results[("clean", name)]
        clean_rows[name] = None if res.error else score(res.outputs, _refs(runs["clean"]), keys)

    # crops and files
    outp = Path(out)
    crop_dir = outp / "stress"
    crop_dir.mkdir(parents=True, exist_ok=True)
    crops = {}
    for case in cases:
        if case.skipped:
            continue
        path = crop_dir / f"{case.name}.png"
        info = crop_case(case, runs, results, table, names, str(path),
                         size=24 if quick else 48, zoom=2 if quick else 3)
        if info:
            crops[case.name] = {**info, "path": str(path)}
    summary = {"table": table, "cases": cases, "methods": names, "clean": clean_rows, "sets": sets,
               "crops": crops, "data": str(data), "spp": spp, "quick": quick, "seed": seed,
               "command": command or "mcdenoise stress", "clean_frames": len(keys), "seconds": round(time.perf_counter() - started, 1),
               "frames": {c.name: len([k for _, k in runs[c.run].frames() if k is not None])
                          for c in cases if not c.skipped}}
    write_csv(summary, outp / "stress.csv")
    (outp / "stress.md").write_text(markdown(summary, outp))
    log(f"stress: wrote {outp / 'stress.md'}, {outp / 'stress.csv'} and {len(crops)} crop(s) in {crop_dir} "
        f"({summary['seconds']} s)")
    return summary


CSV_FIELDS = ("case", "method", "clean_counterpart", "psnr_clean", "psnr_case", "delta_db",
              "relmse_clean", "relmse_case", "nonfinite_output_values", "driver_resets", "error",
              "failed", "skipped")


def write_csv(summary: dict, path: Path) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIELDS)
        for case in summary["cases"]:
            for m in summary["methods"]:
                r = summary["table"][(case.name, m)]
                f = lambda v: "" if v is None else (f"{v:.4f}" if isinstance(v, float) else v)
                w.writerow([case.name, m, case.vs or case.clean, f(r.get("psnr_clean")), f(r.get("psnr_case")),
                            f(r.get("delta_db")), f(r.get("relmse_clean")), f(r.get("relmse_case")),
                            f(r.get("nonfinite")), f(r.get("resets")), r.get("error") or "",
                            r.get("failed") or "", r.get("skipped") or ""])


def _cell(r: dict) -> str:
    if r.get("skipped"):
        return "skipped"
    if r.get("error"):
        return "**crash**"
    txt = f"{r['delta_db']:+.2f}"
    if r.get("nonfinite"):
        txt += " NaN"
    return f"**{txt} fail**" if r.get("failed") else txt


def markdown(summary: dict, out: Path) -> str:
    from runtime.timing import cpu_name

    names, table = summary["methods"], summary["table"]
    L = ["# Stress test", "",
         "What each method loses on hard input, against the same method on the clean counterpart "
         "(`mcdenoise stress`, `training/stress.py`, issue #5).", "",
         "Command:", "", "```", summary["command"], "```", "",
         f"Machine: {cpu_name()}; {summary['seconds']} s for the whole run. Clean case: {summary['spp']} spp "
         f"from `{_rel(summary['data'])}`" + (" (--quick: 2 sequences x 2 frames)" if summary["quick"] else "") + ".",
         "",
         "## PSNR change (dB) against the clean counterpart", "",
         "PSNR is ANF Eq. 14 (tonemapped, over all scored frames of the case); non-finite output "
         "values are counted and scored as 0. `fail` follows the rule below; `NaN`: the output had "
         "non-finite values; the noisy input is the yardstick and never judged.", "",
         "| case | vs | frames | " + " | ".join(names) + " |",
         "|---|---|---:|" + "---:|" * len(names)]
    clean = summary["clean"]
    L.append(f"| *clean, absolute dB* | - | {summary['clean_frames']} | "
             + " | ".join("-" if clean[m] is None else f"{clean[m]['psnr']:.2f}" for m in names) + " |")
    for case in summary["cases"]:
        L.append(f"| {case.name} | {case.vs or case.clean} | {summary['frames'].get(case.name, '-')} | "
                 + " | ".join(_cell(table[(case.name, m)]) for m in names) + " |")
    L += ["", "relMSE on the case / relMSE on the clean counterpart (1: no change):", "",
          "| case | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for case in summary["cases"]:
        if case.skipped:
            continue
        cells = []
        for m in names:
            r = table[(case.name, m)]
            cells.append("-" if r.get("error") or not r.get("relmse_clean") else f"{r['relmse_case'] / r['relmse_clean']:.2f}")
        L.append(f"| {case.name} | " + " | ".join(cells) + " |")
    L += ["", "## Cases", "", "| case | what | clean counterpart | worst region (crop) |", "|---|---|---|---|"]
    for case in summary["cases"]:
        c = summary["crops"].get(case.name)
        crop = "-" if case.skipped else "none"
        if c:
            crop = (f"[{Path(c['path']).name}]({_rel(c['path'], out)}) ({c['method']}, sequence {c['frame'][0]} "
                    f"frame {c['frame'][1]}, x {c['x']} y {c['y']}, {c['size']} px)")
        L.append(f"| {case.name} | {case.what}{' (skipped: ' + case.skipped + ')' if case.skipped else ''} | "
                 f"{case.vs or case.clean} | {crop} |")
    L += ["", "Crops: columns are the input, each method and the reference, tonemapped (ANF Eq. 15) "
          "after undoing the exposure; non-finite pixels are magenta. The window (size above, "
          "enlarged with nearest neighbours) is where the method that lost the most beyond the noisy input "
          "has the largest error increase over its own clean output (perturbation cases, second "
          "row: the clean counterpart) or the largest error (rendered cases).", "",
          "## Failure rule", "",
          f"A method fails a case when it crashes, when any output value is non-finite, when its PSNR on "
          f"the case is below the noisy input's, or when its PSNR change is more than {FAIL_MARGIN_DB:g} dB "
          f"below the noisy input's own change (`training/stress.py`, `judge`).", ""]
    fails = [(c.name, m, table[(c.name, m)]["failed"]) for c in summary["cases"] for m in names
             if table[(c.name, m)].get("failed")]
    L += ["## Failures", ""]
    if fails:
        for m in names:
            mine = [(c, why) for c, mm, why in fails if mm == m]
            if mine:
                L.append(f"- **{m}**: " + "; ".join(f"{c} ({why})" for c, why in mine))
    else:
        L.append("None.")
    notes = []
    for c in summary["cases"]:
        nd = table.get((c.name, "noisy"), {}).get("delta_db")
        for m in names:
            r = table[(c.name, m)]
            if m == "noisy" or r.get("failed") or r.get("delta_db") is None or nd is None:
                continue
            if r["delta_db"] - nd < -NOTE_MARGIN_DB:
                notes.append(f"{m} on {c.name} ({r['delta_db'] - nd:+.1f} dB)")
    if notes:
        L += ["", f"Losses of more than {NOTE_MARGIN_DB:g} dB beyond the noisy input's that are not failures: "
              + "; ".join(notes) + "."]
    errors = {(c.name, m): table[(c.name, m)]["error"] for c in summary["cases"] for m in names
              if table[(c.name, m)].get("error")}
    if errors:
        L += ["", "Errors:", ""]
        seen = set()
        for (c, m), e in errors.items():
            if (m, e) in seen:
                continue
            seen.add((m, e))
            L.append(f"- {m} ({c}{' and others' if sum(1 for (cc, mm), ee in errors.items() if mm == m and ee == e) > 1 else ''}): `{e}`")
    L += ["", "## Absolute scores", "", "| case | method | PSNR clean | PSNR case | relMSE clean | relMSE case | driver resets |",
          "|---|---|---:|---:|---:|---:|---:|"]
    for case in summary["cases"]:
        for m in names:
            r = table[(case.name, m)]
            if r.get("skipped") or r.get("error"):
                continue
            L.append(f"| {case.name} | {m} | {r['psnr_clean']:.2f} | {r['psnr_case']:.2f} | "
                     f"{r['relmse_clean']:.4g} | {r['relmse_case']:.4g} | {'-' if r.get('resets') is None else r['resets']} |")
    L += ["", "## Data", ""]
    if summary["sets"]:
        L += ["| set | folder | scene seeds | frames | render s (s/frame) | command |", "|---|---|---|---:|---:|---|"]
        for name, info in summary["sets"].items():
            if not info.get("folder"):
                L.append(f"| {name} | not rendered | - | - | - | `{info['command']}` |")
                continue
            L.append(f"| {name} | `{_rel(info['folder'])}` | {', '.join(map(str, info.get('seeds', [])))} | "
                     f"{info.get('frames', '-')} | {info.get('render_seconds', '-')} ({info.get('seconds_per_frame', '-')}) | "
                     f"`{_rel_cmd(info['command'])}` |")
        L.append("")
    else:
        L += ["No rendered sets (--data only).", ""]
    L += [f"Perturbation seeds: numpy `default_rng([{summary['seed']}, case, sequence, frame])`. "
          "Render seconds are the renderer's own (manifest), on this machine.", ""]
    code = _code_version()
    if code:
        L += [f"Code: {code}.", ""]
    return "\n".join(L)


def _code_version() -> str | None:
    """"commit abc1234" plus the runtime/method files that differ from it, or None without git."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                              text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "runtime", "models", "training/stress.py"],
                               cwd=REPO, capture_output=True, text=True, timeout=10).stdout.split("\n")
    except (OSError, subprocess.SubprocessError):
        return None
    if not head:
        return None
    changed = sorted(line[3:] for line in dirty if line.strip())
    return f"commit {head}" + (f" with uncommitted {', '.join(changed)}" if changed else "")


def _rel(path: str, base: Path | None = None) -> str:
    try:
        p = Path(path).resolve()
        return os.path.relpath(p, (base or REPO).resolve()) if base else str(p.relative_to(REPO))
    except ValueError:
        return str(path)


def _rel_cmd(cmd: str) -> str:
    return cmd.replace(str(REPO) + os.sep, "")


def add_arguments(p) -> None:
    from runtime.args import add_threads

    p.add_argument("methods", nargs="*",
                   help="ONNX files or oidn-high, oidn-fast, svgf, noisy (default: every models/*.onnx, "
                        + ", ".join(DEFAULT_EXTRA) + ")")
    p.add_argument("--data", default=None, metavar="DIR",
                   help="sequences with per-sample data for the perturbation cases (default: the rendered base set)")
    p.add_argument("--render-dir", default="data/stress", metavar="DIR",
                   help="where the rendered stress sets are cached (default data/stress)")
    p.add_argument("--out", default="docs/results", metavar="DIR", help="where stress.md, stress.csv and stress/ go")
    p.add_argument("--quick", action="store_true",
                   help=f"tiny run: {QUICK_LIMIT[0]} sequences x {QUICK_LIMIT[1]} frames, tiny rendered sets")
    p.add_argument("--spp", type=int, default=4, help="samples per pixel of the clean case (default 4)")
    p.add_argument("--no-render", action="store_true", help="never render: cases whose set is missing are skipped")
    p.add_argument("--seed", type=int, default=0, help="seed of the perturbations (default 0)")
    add_threads(p)


def command_line(args) -> str:
    parts = ["mcdenoise", "stress", *args.methods]
    if args.data:
        parts += ["--data", args.data]
    parts += ["--render-dir", args.render_dir, "--out", args.out, "--spp", str(args.spp)]
    if args.quick:
        parts.append("--quick")
    if args.no_render:
        parts.append("--no-render")
    if args.seed:
        parts += ["--seed", str(args.seed)]
    if args.threads:
        parts += ["--threads", str(args.threads)]
    return " ".join(shlex.quote(x) for x in parts)


def main(args) -> int:
    if args.spp < 1:
        raise ValueError(f"--spp must be >= 1, got {args.spp}")
    stress(args.methods or None, args.data, args.render_dir, args.out, args.quick, args.spp,
           not args.no_render, args.threads, args.seed, command_line(args),
           log=lambda m: print(m, file=sys.stderr))
    return 0
