"""Test sets of the measuring side: what ``bench``, ``stress`` and ``evaluate`` score on.

A test set is a folder of sequences written by ``mcdenoise render`` from held-out scene seeds
(training uses ``--seed 1``: scene seeds 100000+). :class:`TestSet` names one by its render
arguments, :func:`ensure` renders it once (in a subprocess, so Dr.Jit's set-up never depends
on what this process imported) and reuses it afterwards; :func:`read_sequences` loads it and
:func:`at_spp` gives a frame as if rendered with fewer samples. Relative folders are relative
to the current directory, like every other path a command takes.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mcdenoise.runtime import data_path
from mcdenoise.runtime.args import CommandError
from mcdenoise.runtime.frames import MANIFEST, Frame, FrameError, frame_paths, pixel_means, read_frame


@dataclass(frozen=True)
class TestSet:
    """A test set: its folder and the ``mcdenoise render`` arguments that make it.

    ``flags`` are further render flags (camera speed, defocus, floor, ...)."""

    folder: str
    scenes: int
    frames: int
    size: str
    spp: int
    ref_spp: int
    seed: int
    flags: tuple[str, ...] = ()

    def render_args(self, folder: str | None = None) -> list[str]:
        """``mcdenoise`` arguments that render this set into ``folder`` (default its own)."""
        return ["render", "--out", folder or self.folder, "--scenes", str(self.scenes),
                "--frames", str(self.frames), "--size", self.size, "--spp", str(self.spp),
                "--ref-spp", str(self.ref_spp), "--seed", str(self.seed), *self.flags]

    def command(self, folder: str | None = None) -> str:
        return "mcdenoise " + " ".join(self.render_args(folder))


#: Still frames: 16 scenes, one frame each, 8 stored spp (seed 4: never trained or tested on).
STILLS = TestSet("data/bench-stills", 16, 1, "128x128", 8, 512, 4)
#: Sequences: the README's held-out test split (seed 2).
SEQUENCES = TestSet("data/test", 8, 4, "128x128", 4, 512, 2)
#: ``bench --quick`` without --data / --stills: a tiny set for both (seed 4).
QUICK = TestSet("data/bench-quick", 2, 3, "64x64", 8, 64, 4)
#: Long sequences as a real-time user sees them (issue 15): the same two scenes (seed 6) with a
#: slow, medium and fast camera, 24 frames at 256x256, 8 stored spp, 1024-spp references.
LONG_SEQUENCES = {name: TestSet(f"data/long-{name}", 2, 24, "256x256", 8, 1024, 6, ("--camera-speed", speed))
                  for name, speed in (("slow", "0.5"), ("medium", "1"), ("fast", "2"))}
#: Scenes made by hand, unlike the generator's (issue 15: enclosed rooms lit mostly
#: indirectly, textured walls, thin geometry, glossy floors; ``samples/heldout/``): one camera
#: drift each (seed 7), 16 frames at 256x256. Indirect light is noisy, so 2048-spp references
#: (the reference check says how clean). Never train on them.
HELD_OUT_SCENES = ("room_window", "lamp_occluder")
HELD_OUT = {name: TestSet(f"data/heldout-{name}", 1, 16, "256x256", 8, 2048, 7,
                          ("--scene", str(data_path("samples", "heldout", f"{name}.xml"))))
            for name in HELD_OUT_SCENES}


#: Scene seeds of the rendered stress sets: RENDER_SEED * 100000 + i (training uses 1, test 2).
STRESS_SEED = 5
#: Camera speed of the ``fast`` and ``motion-blur`` stress sets (disocclusions, long vectors).
FAST_CAMERA = 4.0
#: Thin-lens aperture multiplier of the ``defocus`` stress set.
APERTURE_SCALE = 6.0
#: Rendered stress sets: name -> (render flags, what it is). Same scenes, only the effect changes.
STRESS_SETS: dict[str, tuple[tuple[str, ...], str]] = {
    "base": (("--defocus", "off"), "pinhole, camera speed 1"),
    "fast": (("--defocus", "off", "--camera-speed", f"{FAST_CAMERA:g}"), f"camera speed {FAST_CAMERA:g}"),
    "defocus": (("--defocus", "on", "--aperture-scale", f"{APERTURE_SCALE:g}"),
                f"thin lens, aperture x{APERTURE_SCALE:g}"),
    "motion-blur": (("--defocus", "off", "--camera-speed", f"{FAST_CAMERA:g}", "--motion-blur", "on"),
                    f"camera motion blur, camera speed {FAST_CAMERA:g}"),
    "glossy": (("--defocus", "off", "--floor", "glossy"), "glossy silver floor"),
}
#: Size of the rendered stress sets: (scenes, frames, size, spp, reference spp), full and --quick.
STRESS_RENDER = {False: (3, 4, "128x128", 4, 256), True: (2, 2, "64x64", 4, 32)}
#: ``stress --quick`` keeps this many sequences x frames of the data set.
QUICK_LIMIT = (2, 2)


def stress_set(name: str, render_dir: str, quick: bool) -> TestSet:
    """The rendered stress set ``name`` (a key of :data:`STRESS_SETS`) cached under ``render_dir``."""
    scenes, frames, size, spp, ref_spp = STRESS_RENDER[quick]
    return TestSet(str(Path(render_dir) / (("quick-" if quick else "") + name)), scenes, frames, size, spp,
                   ref_spp, STRESS_SEED, ("--workers", "1", *STRESS_SETS[name][0]))


def is_complete(ts: TestSet, folder: str | None = None) -> bool:
    """Whether ``folder`` (default ``ts.folder``) holds every sequence of ``ts``, finished with
    the same render settings (:func:`training.render.command.finished`)."""
    from mcdenoise.runtime.cli import build_parser

    parser, command = build_parser("render")
    return command.finished(parser.parse_args(ts.render_args(folder)[1:]))


def render(args: list[str], what: str, log=print) -> float:
    """Run ``mcdenoise <args>`` (a render) in a subprocess; returns its wall seconds. A failed
    render raises a one-line :class:`CommandError` with the render's own last error line."""
    log(f"rendering {what}: mcdenoise {' '.join(args)}")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "mcdenoise.runtime.cli", *args], capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise CommandError(f"rendering {what} failed (mcdenoise {' '.join(args)}): {tail}")
    return time.perf_counter() - t0


def ensure(ts: TestSet, folder: str | None = None, render_missing: bool = True, what: str = "the test set",
           log=print) -> tuple[str | None, dict]:
    """The folder of ``ts`` (default ``ts.folder``), rendered first unless it is complete.

    Returns (folder, info): info has the render ``command``, ``wall_seconds`` of this call's
    render (None when reused) and, from the manifest, ``render_seconds``, ``frames``,
    ``seconds_per_frame``, scene ``seeds`` and ``variant``. With ``render_missing`` False an
    incomplete set gives (None, info) instead of a render."""
    folder = folder or ts.folder
    info: dict = {"command": ts.command(folder), "wall_seconds": None}
    if not is_complete(ts, folder):
        if not render_missing:
            return None, info
        info["wall_seconds"] = round(render(ts.render_args(folder), what, log), 1)
    man = json.loads((Path(folder) / MANIFEST).read_text())
    seqs = man.get("sequences", [])
    secs = sum(e.get("render_seconds", 0.0) for e in seqs)
    frames = sum(e.get("frames", 0) for e in seqs)
    info.update(render_seconds=round(secs, 1), frames=frames, seconds_per_frame=round(secs / max(frames, 1), 2),
                seeds=[e.get("scene_seed") for e in seqs], variant=(man.get("settings") or {}).get("variant"))
    return folder, info


def reference_check(ts: TestSet, folder: str | None = None, log=print) -> dict:
    """How well two independent references of each sequence's first frame agree
    (``mcdenoise render --check-references``, run once and kept in the folder): the JSON the
    render command writes, with ``min_db`` the worst PSNR (ANF Eq. 14) over the sequences."""
    from mcdenoise.training.render.command import REFERENCE_CHECK

    folder = folder or ts.folder
    path = Path(folder) / REFERENCE_CHECK
    try:
        data = json.loads(path.read_text())
        if data.get("ref_spp") == ts.ref_spp:
            return data
    except (OSError, ValueError):
        pass
    render([*ts.render_args(folder), "--check-references"], f"second references of {folder}", log)
    return json.loads(path.read_text())


def sequences(root: str) -> list[list[str]]:
    """Frame paths per sequence folder under ``root`` (or ``root`` itself if it holds frames).

    A sequence ``mcdenoise render`` has not finished (being rendered, or interrupted) is an
    error, not a shorter sequence: scoring its first frames would silently compare methods
    on another set than the one named (an evaluation started while a render was finishing
    scored 43 of long-slow's 48 frames)."""
    from mcdenoise.training.dataset import PARTIAL

    rootp = Path(root)
    if not rootp.is_dir():
        raise FrameError(f"{root}: dataset folder does not exist")
    folders = [rootp] if frame_paths(root) else [p for p in sorted(rootp.iterdir()) if p.is_dir() and frame_paths(p)]
    if not folders:
        raise FrameError(f"{root}: no sequences of frame_*.exr")
    unfinished = [str(p) for p in folders if (p / PARTIAL).exists()]
    if unfinished:
        raise FrameError(f"{unfinished[0]}: not finished rendering ({PARTIAL} is there{f', and {len(unfinished) - 1} more' if len(unfinished) > 1 else ''}): "
                         "re-run the render command that made it (it resumes), then score it")
    return [frame_paths(p) for p in folders]


def read_sequences(data: str, stills: bool = False, limit: tuple[int, int] | None = None) -> list[list[Frame]]:
    """Frames (with per-sample layers and a reference) of every sequence under ``data``: only
    the first frame of each with ``stills``; at most ``limit`` = (sequences, frames)."""
    paths = sequences(data)
    if limit:
        paths = [s[:limit[1]] for s in paths[:limit[0]]]
    out = []
    for seq in paths:
        frames = [read_frame(p) for p in (seq[:1] if stills else seq)]
        for f in frames:
            if f.reference is None:
                raise FrameError(f"{f.path}: no reference layer to score against")
        out.append(frames)
    return out


def stored_spp(seqs: list[list[Frame]]) -> int:
    """Samples per pixel every frame of ``seqs`` holds (the smallest)."""
    return min(f.spp for s in seqs for f in s)


def with_samples(frame: Frame, samples: np.ndarray) -> Frame:
    """``frame`` with per-sample data ``samples`` (S, H, W, F) and its pixel layers recomputed
    from them (:func:`runtime.frames.pixel_means`); motion (a copy), valid, reference and meta kept."""
    px = pixel_means(samples)
    return Frame(**px, motion=None if frame.motion is None else frame.motion.copy(),
                 valid=frame.valid, reference=frame.reference, samples=samples,
                 meta=dict(frame.meta, spp=int(samples.shape[0])), path=frame.path)


def at_spp(frame: Frame, n: int) -> Frame:
    """The frame as if rendered with its first ``n`` stored samples per pixel; its per-sample
    data is a copy of those ``n`` samples (so a perturbation may change it in place)."""
    if frame.samples is None:
        raise FrameError(f"{frame.path}: no per-sample layers, cannot take {n} of its samples per pixel")
    if n > frame.spp:
        raise FrameError(f"{frame.path}: holds {frame.spp} samples per pixel, {n} requested")
    return with_samples(frame, frame.samples[:n].copy())
