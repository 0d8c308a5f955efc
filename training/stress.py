"""``mcdenoise stress [METHOD...]``: how much each denoising method degrades on hard input.

For every method (:func:`training.methods.load_method`: shipped ONNX models through the runtime
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

Cases from rendered sets (``mcdenoise render``, held-out scene seeds ``STRESS_SEED`` * 100000
+ i, cached under ``--render-dir``; same scenes as the ``base`` set, only the effect changes):

* ``disocclusion``: the camera moves :data:`FAST_CAMERA` x as fast (vs ``base``);
* ``defocus``: a thin lens with :data:`APERTURE_SCALE` x the generator's aperture (vs ``base``);
* ``motion-blur``: camera motion blur at the fast camera speed (vs ``disocclusion``'s set, the
  same camera path without blur);
* ``glossy``: the floor is glossy silver (GGX alpha 0.05): large reflections whose motion
  vectors (which follow the first hit) are wrong (vs ``base``).

Scores: PSNR (ANF Eq. 14) and relMSE (:mod:`training.metrics`) over all scored frames of a case,
with non-finite output values counted and set to 0 before scoring.  The failure rule is
:func:`judge`.  Outputs: ``stress.md``, ``stress.csv`` and ``stress/<case>.png`` in ``--out``.
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from mcdenoise.runtime.frames import PIXEL_LAYERS, SAMPLE_GROUPS, Frame, FrameError
from mcdenoise.training.dataset import add_fireflies
from mcdenoise.training.report import (
    compose,
    display,
    error_map,
    stress_markdown,
    worst_window,
    write_stress_csv,
)
from mcdenoise.training.scoring import score
from mcdenoise.training.testsets import (
    APERTURE_SCALE,
    FAST_CAMERA,
    QUICK_LIMIT,
    at_spp,
    ensure,
    read_sequences,
    stress_set,
    with_samples,
)

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
#: Methods run by default besides the shipped ONNX models.
DEFAULT_EXTRA = ("oidn-high", "svgf", "noisy")



# ----------------------------------------------------------------------------------------------
# Perturbations (pure functions of a frame with per-sample data and a random generator)
# ----------------------------------------------------------------------------------------------


def inject_fireflies(frame: Frame, rng: np.random.Generator, factor: float = FIREFLY_FACTOR,
                     density: float = FIREFLY_DENSITY) -> tuple[Frame, np.ndarray]:
    """Outlier samples: about ``density`` per pixel get radiance ``factor`` x the mean of the
    frame's clean colour (all pixels and channels), in every channel.  Returns the new frame
    and the (n, 3) array of (sample, y, x) changed."""
    h, w = frame.size
    samples = frame.samples.copy()
    where = add_fireflies(samples, rng, factor * float(np.mean(frame.color, dtype=np.float64)),
                          max(1, int(round(density * h * w))))
    return with_samples(frame, samples), where


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




def _strip(seqs, keep: bool = False):
    """Drop per-sample data to keep memory small, unless ``keep`` (a per-sample method, ANF,
    is among the methods: it reads the samples)."""
    if keep:
        return seqs
    for s in seqs:
        for fr in s:
            fr.samples = None
    return seqs


def reads_samples(name: str) -> bool:
    """Whether method ``name`` is an mcdenoise ONNX file with a per-sample input."""
    if not name.endswith(".onnx"):
        return False
    import onnxruntime as ort

    from mcdenoise.runtime.contract import parse_contract

    meta = ort.InferenceSession(name, providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    return parse_contract(meta).samples_input is not None


def perturbation_runs(data: list[list[Frame]], spp: int, seed: int, keep_samples: bool = False) -> tuple[dict, list[Case]]:
    """The runs and cases made from the data set's frames (see the module docstring).  The
    runs' frames carry no per-sample data (dropped once the pixel layers are made) unless
    ``keep_samples``."""
    clean = [[at_spp(f, spp) for f in s] for s in data]
    runs: dict[str, Run] = {}
    cases = []

    def add(name: str, seqs, keys=None, scale: float = 1.0) -> None:
        runs[name] = Run(name, _strip(seqs, keep_samples), keys or _keys(seqs), scale)

    def rng(case_id: int, i: int, t: int):
        return np.random.default_rng([seed, case_id, i, t])

    add("fireflies", [[inject_fireflies(f, rng(1, i, t))[0] for t, f in enumerate(s)] for i, s in enumerate(clean)])
    cases.append(Case("fireflies", f"{FIREFLY_DENSITY * 1e3:g} sample per 1000 pixels at "
                      f"{FIREFLY_FACTOR:g}x the image mean (ANF Fig. 3)", "fireflies", "clean", True))
    add("nan-inf", [[inject_nonfinite(f, rng(2, i, t))[0] for t, f in enumerate(s)] for i, s in enumerate(clean)])
    cases.append(Case("nan-inf", f"{NONFINITE_DENSITY * 1e3:g} sample per 1000 pixels each with NaN "
                      "radiance, +Inf radiance, NaN in every feature", "nan-inf", "clean", True))
    one = [[at_spp(f, 1) for f in s] for s in data]
    _strip(clean, keep_samples)
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
              for k in (layer.name for layer in PIXEL_LAYERS)}     # every layer: a model may read any
    return Frame(**arrays, samples=None if fr.samples is None else fr.samples.copy(),
                 meta=json.loads(json.dumps(fr.meta)), path=fr.path)


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


def case_score(outputs: dict, refs: dict, keys: list, scale: float = 1.0) -> dict:
    """PSNR (ANF Eq. 14) and relMSE (:func:`training.scoring.score`) over the frames ``keys``
    of a run, non-finite output set to 0 first, outputs and references times ``scale``."""
    outs = [np.nan_to_num(outputs[k], nan=0.0, posinf=0.0, neginf=0.0) * np.float32(scale) for k in keys]
    return score(outs, [refs[k] * np.float32(scale) for k in keys], [len(keys)], which=("psnr", "relmse"))


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


# ----------------------------------------------------------------------------------------------
# The suite
# ----------------------------------------------------------------------------------------------

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
        panels = [display(_inputs(r)[key][sl], r.scale, (s, s, 3))]
        for m in methods:
            res = results.get((res_run, m))
            out = None if res is None or res.error else res.outputs.get(key)
            panels.append(display(None if out is None else out[sl], r.scale, (s, s, 3)))
        panels.append(display(_refs(r)[key][sl], r.scale, (s, s, 3)))
        return panels

    rows = [(case.name, row(run, case.run))]
    if case.aligned:
        rows.append(("clean", row(clean, case.clean)))
    compose(rows, ["input", *methods, "reference"], path, zoom)
    return {"method": worst, "frame": list(key), "y": y, "x": x, "size": s}




def stress(methods: list[str] | None = None, data: str | None = None, render_dir: str = "data/stress",
           out: str = "docs/results", quick: bool = False, spp: int = 4, render: bool = True,
           threads: int = 0, seed: int = 0, command: str | None = None, log=print) -> dict:
    """Run the suite and write ``stress.md``, ``stress.csv`` and ``stress/<case>.png`` into
    ``out``.  Returns {"table": {(case, method): row}, "cases": [...], "methods": [...], ...}."""
    from mcdenoise.training.methods import load_method, shipped_models

    methods = list(methods) if methods else [*shipped_models(), *DEFAULT_EXTRA]
    started = time.perf_counter()
    sets: dict[str, dict] = {}
    limit = QUICK_LIMIT if quick else None
    if data is None:
        folder, info = ensure(stress_set("base", render_dir, quick), render_missing=render,
                              what="stress set 'base'", log=log)
        if folder is None:
            raise FrameError(f"no --data and the base stress set is not rendered in {render_dir} (--no-render)")
        sets["base"] = {**info, "folder": folder}
        data = folder
    keep = any(reads_samples(m) for m in methods)
    data_seqs = read_sequences(data, limit=limit)
    runs, cases = perturbation_runs(data_seqs, spp, seed, keep)
    del data_seqs
    # rendered sets; the base set is the clean run when it is the data set
    alias = {"base": "clean"} if "base" in sets else {}
    for case_name, set_name, clean_name, what in RENDERED_CASES:
        missing = False
        for name in (set_name, clean_name):
            if alias.get(name, name) in runs:
                continue
            folder, info = ensure(stress_set(name, render_dir, quick), render_missing=render,
                                  what=f"stress set {name!r}", log=log)
            sets[name] = {**info, "folder": folder}
            if folder is None:
                missing = True
                continue
            seqs = _strip([[at_spp(f, spp) for f in s] for s in read_sequences(folder, limit=limit)], keep)
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
                a = case_score(res.outputs, refs, keys, run.scale)
                b = case_score(cres.outputs, crefs, keys, clean.scale)
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
        clean_rows[name] = None if res.error else case_score(res.outputs, _refs(runs["clean"]), keys)

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
               "command": command or "mcdenoise stress",
               "fail_margin_db": FAIL_MARGIN_DB, "note_margin_db": NOTE_MARGIN_DB, "clean_frames": len(keys), "seconds": round(time.perf_counter() - started, 1),
               "frames": {c.name: len([k for _, k in runs[c.run].frames() if k is not None])
                          for c in cases if not c.skipped}}
    write_stress_csv(summary, outp / "stress.csv")
    (outp / "stress.md").write_text(stress_markdown(summary, outp))
    log(f"stress: wrote {outp / 'stress.md'}, {outp / 'stress.csv'} and {len(crops)} crop(s) in {crop_dir} "
        f"({summary['seconds']} s)")
    return summary


def add_arguments(p) -> None:
    from mcdenoise.runtime.args import add_data, add_seed, add_threads

    p.add_argument("methods", nargs="*",
                   help="ONNX files or oidn-high, oidn-fast, svgf, noisy (default: every models/*.onnx, "
                        + ", ".join(DEFAULT_EXTRA) + ")")
    add_data(p, required=False, default="the rendered base stress set; its per-sample data makes the perturbation cases")
    p.add_argument("--render-dir", default="data/stress", metavar="DIR",
                   help="where the rendered stress sets are cached (default data/stress)")
    p.add_argument("--out", default="docs/results", metavar="DIR", help="where stress.md, stress.csv and stress/ go")
    p.add_argument("--quick", action="store_true",
                   help=f"tiny run: {QUICK_LIMIT[0]} sequences x {QUICK_LIMIT[1]} frames, tiny rendered sets")
    p.add_argument("--spp", type=int, default=4, help="samples per pixel of the clean case (default 4)")
    p.add_argument("--no-render", action="store_true", help="never render: cases whose set is missing are skipped")
    add_seed(p, "where fireflies and NaN/Inf samples are injected")
    add_threads(p)




def main(args) -> int:
    from mcdenoise.runtime.cli import command_line

    if args.spp < 1:
        raise ValueError(f"--spp must be >= 1, got {args.spp}")
    stress(args.methods or None, args.data, args.render_dir, args.out, args.quick, args.spp,
           not args.no_render, args.threads, args.seed, command_line("stress", args),
           log=lambda m: print(m, file=sys.stderr))
    return 0
