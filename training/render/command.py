"""``mcdenoise render``: render per-sample training/test sequences with Mitsuba 3.

Procedural scenes (default) or a user's scene file (``--scene``), each a camera fly-through of
``--frames`` frames, written as ``<out>/<scene>/frame_<t>.exr`` (``runtime.frames``) plus
``<out>/manifest.json``.  Every sequence folder also gets ``scene/`` with what re-renders it:
``scene.xml`` and ``scene.json`` (procedural scenes), meshes and textures, ``camera_path.json``.
Finished sequences whose settings match are kept when the command is run again.

Only argparse and runtime.args are imported at module level, so ``--help`` works without Mitsuba.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

from mcdenoise.runtime.args import add_seed, add_size
from mcdenoise.training.dataset import PARTIAL
from mcdenoise.training.render.variant import VARIANTS

#: Scene seed = --seed * SCENE_STRIDE + scene index, so held-out splits can be made by seed
#: and two base seeds never share a scene.
SCENE_STRIDE = 100_000
#: File the reference check writes into the output folder (see check_references).
REFERENCE_CHECK = "reference_check.json"


def probability(text: str) -> float:
    """"on" / "off" / a number in [0, 1] -> probability."""
    t = text.strip().lower()
    if t in ("on", "yes", "true"):
        return 1.0
    if t in ("off", "no", "false"):
        return 0.0
    try:
        v = float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected on, off or a probability in [0, 1], got {text!r}") from None
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"probability must be in [0, 1], got {text!r}")
    return v


def _positive(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    p.add_argument("--scenes", type=_positive, default=8,
                   help="number of sequences: procedural scenes, or camera paths around --scene (default 8)")
    p.add_argument("--frames", type=_positive, default=None,
                   help="frames per sequence (default 8, or the length of --camera-path)")
    p.add_argument("--spp", type=_positive, default=8, help="samples per pixel stored per sample (default 8)")
    p.add_argument("--ref-spp", type=_positive, default=256,
                   help="samples per pixel of the reference, independent seed (default 256)")
    add_size(p, "256x256")
    add_seed(p, "the procedural scenes, their camera paths and the sample passes; scene seed = seed x 100000 + index")
    p.add_argument("--defocus", type=probability, default=0.5, metavar="P|on|off",
                   help="probability a procedural scene gets a thin lens (default 0.5); a --scene keeps its own lens")
    p.add_argument("--motion-blur", type=probability, default=0.0, metavar="P|on|off",
                   help="probability a sequence gets camera motion blur: each sample pass at its own "
                        "shutter time, stored in the 'time' feature (default off)")
    p.add_argument("--camera-speed", type=float, default=1.0,
                   help="scale of the camera's motion per frame (default 1)")
    p.add_argument("--aperture-scale", type=float, default=1.0,
                   help="multiply procedural scenes' thin-lens aperture radius (stronger defocus; default 1)")
    p.add_argument("--enclosed", type=probability, default=0.0, metavar="P|on|off",
                   help="probability a procedural scene is closed into a room lit mostly indirectly: walls all "
                        "round, a ceiling, light through a window opening and from a lamp behind an occluder, thin "
                        "bars, often a glossy floor (default off; the rest of each scene is unchanged)")
    p.add_argument("--floor", choices=("scene", "glossy", "mirror"), default="scene",
                   help="procedural floor material: the scene's own (default), glossy silver (GGX alpha 0.05) "
                        "or a silver mirror")
    p.add_argument("--variant", choices=VARIANTS, default="auto",
                   help="Mitsuba variant; auto picks llvm_ad_rgb when an LLVM >= 16 library is found, else "
                        "scalar_rgb; cuda_ad_rgb renders on an NVIDIA GPU")
    p.add_argument("--scene", metavar="FILE.xml", help="render a Mitsuba scene file instead of procedural scenes")
    p.add_argument("--camera-path", metavar="FILE.json",
                   help="per-frame to_world matrices for --scene (as written to <seq>/scene/camera_path.json)")
    p.add_argument("--workers", type=_positive, default=1,
                   help="render this many sequences at once in separate processes (default 1)")
    p.add_argument("--pixel-only", action="store_true",
                   help="write pixel layers only, no per-sample layers (S samples still averaged into colour)")
    p.add_argument("--overwrite", action="store_true", help="re-render sequences that are already complete")
    p.add_argument("--check-references", action="store_true",
                   help="then render a second, independent reference of each sequence's first frame and write "
                        f"how well the two agree (PSNR, ANF Eq. 14) to <out>/{REFERENCE_CHECK}: a reference must "
                        "be much cleaner than the best method it scores")


# ----------------------------------------------------------------------------------------------
# Jobs and the manifest
# ----------------------------------------------------------------------------------------------

def _settings(args, variant: str) -> dict:
    """Everything that changes a sequence's pixels (a finished sequence is kept only if equal)."""
    w, h = args.size
    return {"spp": args.spp, "ref_spp": args.ref_spp, "size": [w, h], "variant": variant,
            "defocus_probability": args.defocus, "motion_blur_probability": args.motion_blur,
            "camera_speed": args.camera_speed,
            "scene": os.path.abspath(args.scene) if args.scene else None,
            "camera_path": os.path.abspath(args.camera_path) if args.camera_path else None,
            # only when changed, so data sets rendered before these options existed stay complete
            **({"aperture_scale": args.aperture_scale} if getattr(args, "aperture_scale", 1.0) != 1.0 else {}),
            **({"floor": args.floor} if getattr(args, "floor", "scene") != "scene" else {}),
            **({"enclosed_probability": args.enclosed} if getattr(args, "enclosed", 0.0) else {})}


def plan(args) -> list[dict]:
    """One job per sequence: scene seed, folder name, frames, and the passes it will render
    (for the progress bar).  Pure: no rendering, no Mitsuba."""
    from mcdenoise.training.render import procedural
    from mcdenoise.training.render.renderer import passes_per_frame

    jobs = []
    for i in range(args.scenes):
        seed = args.seed * SCENE_STRIDE + i
        defocus, blur = procedural.scene_flags(seed, args.defocus, args.motion_blur)
        frames = args.frames
        if args.scene:
            stem = os.path.splitext(os.path.basename(args.scene))[0]
            name = f"{stem}_{seed:07d}"
            if frames is None and args.camera_path:
                from mcdenoise.training.render.camera import load_camera_path

                frames = len(load_camera_path(args.camera_path)[0])
        else:
            name = procedural.scene_name(seed)
        frames = 8 if frames is None else frames
        jobs.append({"seed": seed, "name": name, "frames": frames, "motion_blur": blur,
                     "defocus": defocus, "passes": frames * passes_per_frame(args.spp, args.ref_spp, blur)})
    return jobs


def _complete(out: str, entry: dict | None, settings: dict, job: dict) -> bool:
    from mcdenoise.runtime.frames import frame_name

    if not entry or entry.get("settings") != settings or entry.get("frames") != job["frames"]:
        return False
    folder = os.path.join(out, job["name"])
    return all(os.path.isfile(os.path.join(folder, frame_name(t))) for t in range(job["frames"]))


def finished(args) -> bool:
    """Whether ``args.out`` already holds every sequence these arguments plan, each finished with
    the same settings, whichever Mitsuba variant rendered it (the variants differ in noise, not
    in scenes): test sets are reused instead of re-rendered on a machine with the other one."""
    from mcdenoise.runtime.frames import frame_name

    want = {k: v for k, v in _settings(args, "").items() if k != "variant"}
    entries = {e["folder"]: e for e in _read_manifest(os.path.abspath(args.out)).get("sequences", [])}
    for job in plan(args):
        entry = entries.get(job["name"])
        if not entry or entry.get("frames") != job["frames"]:
            return False
        if {k: v for k, v in (entry.get("settings") or {}).items() if k != "variant"} != want:
            return False
        folder = os.path.join(args.out, job["name"])
        if not all(os.path.isfile(os.path.join(folder, frame_name(t))) for t in range(job["frames"])):
            return False
    return True


def _write_manifest(out: str, manifest: dict) -> None:
    from mcdenoise.runtime.frames import MANIFEST

    path = os.path.join(out, MANIFEST)
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(manifest, fh, indent=1, sort_keys=True)
    os.replace(tmp, path)


def _read_manifest(out: str) -> dict:
    from mcdenoise.runtime.frames import MANIFEST

    path = os.path.join(out, MANIFEST)
    if not os.path.isfile(path):
        return {}
    try:
        with open(path) as fh:
            return json.load(fh)
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: existing manifest is unreadable ({e}); move it away or pick another --out") from None


# ----------------------------------------------------------------------------------------------
# Running a job (in this process or a worker)
# ----------------------------------------------------------------------------------------------

def _sequence(mi, a: argparse.Namespace, job: dict, folder: str):
    """The renderer's Sequence of ``job``: the user's scene, or the procedural scene of its seed
    (exported into ``folder``/scene)."""
    from mcdenoise.training.render import procedural
    from mcdenoise.training.render.renderer import load_procedural, user_scene

    w, h = a.size
    if a.scene:
        return user_scene(mi, a.scene, (w, h), job["seed"], job["frames"], a.camera_path, a.camera_speed,
                          job["motion_blur"])
    spec = procedural.generate(job["seed"], w, h, job["frames"], a.defocus, a.motion_blur, a.camera_speed,
                               getattr(a, "aperture_scale", 1.0), getattr(a, "floor", "scene"),
                               getattr(a, "enclosed", 0.0))
    return load_procedural(mi, spec, folder, job["frames"], a.spp)


def _resume_frames(folder: str, key: dict, overwrite: bool):
    """``keep(t)`` for ``render_sequence``: a sequence interrupted mid-way (a session that ended,
    a killed job) resumes at its first missing frame.  Frames are kept only when the folder's
    ``.partial.json`` says they were rendered with exactly these settings (written before the
    first frame; frames are written atomically, so a file that exists is whole)."""
    from mcdenoise.runtime.frames import frame_name

    os.makedirs(folder, exist_ok=True)
    marker = os.path.join(folder, PARTIAL)
    key = json.loads(json.dumps(key))       # the JSON form, so tuples compare equal to lists
    try:
        with open(marker) as fh:
            same = json.load(fh) == key
    except (OSError, ValueError):
        same = False
    if overwrite or not same:
        # Frames of other settings go first: a later resume must never keep one of them.
        for t in range(int(key["job"]["frames"])):
            try:
                os.remove(os.path.join(folder, frame_name(t)))
            except FileNotFoundError:
                pass
        tmp = marker + ".tmp"
        with open(tmp, "w") as fh:
            json.dump(key, fh, sort_keys=True)
        os.replace(tmp, marker)
        return None
    return lambda t: os.path.isfile(os.path.join(folder, frame_name(t)))


def run_job(job: dict, args_dict: dict, variant: str, progress=None) -> dict:
    """Render one sequence; returns its manifest entry.  ``progress``: a callable taking the
    number of finished render calls, or a queue to put them on (worker processes)."""
    from mcdenoise.training.render.renderer import RenderError, one_line, render_sequence
    from mcdenoise.training.render.variant import init_mitsuba

    mi = init_mitsuba(variant)
    a = argparse.Namespace(**args_dict)
    w, h = a.size
    folder = os.path.join(a.out, job["name"])
    try:
        seq = _sequence(mi, a, job, folder)
        report = progress.put if hasattr(progress, "put") else progress
        keep = _resume_frames(folder, {"settings": _settings(a, variant), "job": job,
                                       "pixel_only": bool(getattr(a, "pixel_only", False))},
                              overwrite=bool(getattr(a, "overwrite", False)))
        resumed = sum(bool(keep(t)) for t in range(job["frames"])) if keep else 0
        seconds = render_sequence(mi, seq, folder, a.spp, a.ref_spp, variant, progress=report,
                                  pixel_only=getattr(a, "pixel_only", False), keep=keep)
        os.remove(os.path.join(folder, PARTIAL))
        # A resumed sequence's time per frame is of the frames this run rendered; its total is
        # extrapolated from that (the interrupted run's clock is gone).
        per_frame = seconds / max(seq.frames - resumed, 1)
    except RenderError:
        raise
    except Exception as e:  # one line naming the sequence, not a traceback (also from worker processes)
        raise RenderError(f"{job['name']} (scene seed {job['seed']}): {one_line(e)}") from e
    return {"folder": job["name"], "scene": seq.name, "scene_seed": seq.seed, "frames": seq.frames,
            "spp": a.spp, "ref_spp": a.ref_spp, "size": [w, h], "variant": variant,
            "defocus": seq.defocus, "motion_blur": seq.motion_blur, "source": seq.source,
            "camera": seq.intrinsics.to_json(), "render_seconds": round(per_frame * seq.frames, 3),
            "seconds_per_frame": round(per_frame, 3), **({"resumed_frames": resumed} if resumed else {}),
            **(seq.info or {})}


def _run_serial(todo, args_dict, variant, bar, done):
    for k, job in enumerate(todo):
        per_frame = job["passes"] // job["frames"]
        count = [0]

        def tick(n: int) -> None:  # called only while this job runs, so the loop variables hold
            count[0] += n
            frame = min(count[0] // per_frame + 1, job["frames"])
            bar.set_postfix_str(f"scene {k + 1}/{len(todo)} frame {frame}/{job['frames']}", refresh=False)
            bar.update(n)

        tick(0)
        done(run_job(job, args_dict, variant, progress=tick))


def _run_parallel(todo, args_dict, variant, bar, done, workers):
    import multiprocessing as mp
    import queue as queue_mod
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # Each worker keeps Dr.Jit's full thread pool: with dr.set_thread_count(1) scene loading
    # deadlocks, and a little oversubscription costs less than idle cores between render calls.
    ctx = mp.get_context("spawn")  # fork would copy an initialised Dr.Jit/LLVM state
    with ctx.Manager() as manager, ProcessPoolExecutor(workers, mp_context=ctx) as pool:
        q = manager.Queue()
        pending = {pool.submit(run_job, job, args_dict, variant, q) for job in todo}
        finished = 0
        try:
            while pending:
                ready, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                while True:
                    try:
                        bar.update(q.get_nowait())
                    except queue_mod.Empty:
                        break
                for fut in ready:
                    done(fut.result())
                    finished += 1
                    bar.set_postfix_str(f"scenes done {finished}/{len(todo)}")
        except BaseException:
            for fut in pending:
                fut.cancel()
            raise


def main(args) -> int:
    from tqdm import tqdm

    from mcdenoise.training.render.variant import announce, choose_variant, init_mitsuba

    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if args.scenes > SCENE_STRIDE:
        raise ValueError(f"--scenes must be <= {SCENE_STRIDE} (scene seeds are seed*{SCENE_STRIDE}+index)")
    if args.camera_speed < 0:
        raise ValueError(f"--camera-speed must be >= 0, got {args.camera_speed}")
    if not args.aperture_scale > 0:
        raise ValueError(f"--aperture-scale must be > 0, got {args.aperture_scale}")
    if args.scene and (args.aperture_scale != 1.0 or args.floor != "scene" or args.enclosed):
        raise ValueError("--aperture-scale, --floor and --enclosed change procedural scenes; a --scene keeps its own")
    if args.camera_path and not args.scene:
        raise ValueError("--camera-path needs --scene (procedural scenes make their own camera paths)")
    if args.scene and not os.path.isfile(args.scene):
        raise FileNotFoundError(f"{args.scene}: scene file not found")
    if args.camera_path and not os.path.isfile(args.camera_path):
        raise FileNotFoundError(f"{args.camera_path}: camera path file not found")

    variant, reason = choose_variant(args.variant)
    announce(variant, reason)
    init_mitsuba(variant)  # fail here, clearly, rather than in a worker

    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    args_dict = {**vars(args), "out": out}
    args_dict.pop("func", None)
    settings = _settings(args, variant)
    jobs = plan(args)
    manifest = _read_manifest(out)
    entries = {e["folder"]: e for e in manifest.get("sequences", [])}
    todo = [j for j in jobs if args.overwrite or not _complete(out, entries.get(j["name"]), settings, j)]
    kept = len(jobs) - len(todo)
    if kept:
        print(f"mcdenoise render: keeping {kept} finished sequence(s) with the same settings "
              f"(--overwrite re-renders them)", file=sys.stderr)

    manifest = {"generator": "mcdenoise render", "settings": {**settings, "seed": args.seed,
                                                              "scenes": args.scenes, "frames": args.frames},
                "sequences": sorted(entries.values(), key=lambda e: e["folder"])}

    def done(entry: dict) -> None:
        entry["settings"] = settings
        entries[entry["folder"]] = entry
        manifest["sequences"] = sorted(entries.values(), key=lambda e: e["folder"])
        _write_manifest(out, manifest)

    start = time.perf_counter()
    total = sum(j["passes"] for j in todo)
    with tqdm(total=total, unit="pass", desc="render", file=sys.stderr, dynamic_ncols=True,
              disable=total == 0) as bar:
        if args.workers > 1 and len(todo) > 1:
            _run_parallel(todo, args_dict, variant, bar, done, min(args.workers, len(todo)))
        else:
            _run_serial(todo, args_dict, variant, bar, done)
    _write_manifest(out, manifest)
    frames = sum(j["frames"] for j in todo)
    elapsed = time.perf_counter() - start
    print(f"rendered {len(todo)} sequence(s), {frames} frame(s) in {elapsed:.1f} s"
          + (f" ({elapsed / frames:.2f} s/frame)" if frames else "") + f" into {out}")
    if args.check_references:
        check_references(args_dict, jobs, variant)
    return 0


def check_references(args_dict: dict, jobs: list[dict], variant: str) -> dict:
    """A second reference of each sequence's first frame (the renderer's independent seed
    stream 2, same spp) against the stored one: PSNR (ANF Eq. 14) per sequence, written to
    ``<out>/REFERENCE_CHECK`` and printed. The scene is rebuilt from its seed, as it was
    rendered (procedural scenes) or from the same scene file."""
    import tempfile

    from mcdenoise.runtime.frames import frame_name, read_frame
    from mcdenoise.training.metrics import psnr
    from mcdenoise.training.render.renderer import SequenceRenderer
    from mcdenoise.training.render.variant import init_mitsuba

    mi = init_mitsuba(variant)
    a = argparse.Namespace(**args_dict)
    w, h = a.size
    result = {"frame": 0, "ref_spp": a.ref_spp, "stream": 2, "variant": variant, "sequences": {}}
    for job in jobs:
        with tempfile.TemporaryDirectory() as tmp:
            seq = _sequence(mi, a, job, tmp)
            second, _ = SequenceRenderer(mi, seq, spp=1, ref_spp=a.ref_spp, variant=variant).reference(0, stream=2)
        first = read_frame(os.path.join(a.out, job["name"], frame_name(0)), samples=False).reference
        result["sequences"][job["name"]] = db = psnr(first, second)
        print(f"{job['name']}: two independent {a.ref_spp}-spp references of frame 0 agree to {db:.2f} dB")
    vals = list(result["sequences"].values())
    result["min_db"] = min(vals) if vals else None
    with open(os.path.join(a.out, REFERENCE_CHECK), "w") as fh:
        json.dump(result, fh, indent=1, sort_keys=True)
    return result
