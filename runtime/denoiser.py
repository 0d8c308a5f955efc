"""The runtime denoise API: load an mcdenoise ONNX file and denoise a sequence frame by frame.

    den = Denoiser.load("models/wskpn-3.onnx")
    for frame in frames:            # runtime.frames.Frame, or a dict of (H, W, C) arrays
        image = den(frame)          # (H, W, 3) float32 linear HDR
    den.reset()                     # e.g. before an unrelated sequence

The driver knows nothing about any one method: the file's contract (metadata) says which
inputs are frame layers, which are temporal state, and which stages the graph has.  State is
kept here: after each frame the model's ``next_<name>`` outputs and the frame's guide buffers
(world position, world normal, depth) are stored; at the next frame they are reprojected with
the frame's motion vectors and a consistency test (:mod:`runtime.temporal`) and fed back.

Bad input never crashes with a traceback and never reaches the state: non-finite, negative and
huge radiance is sanitised (counted in :attr:`Denoiser.report`, said once per kind); a missing
layer or wrong shape raises :class:`runtime.frames.FrameError` naming it; a resolution change
or a camera cut resets the state (said once per event): one flagged (``meta["cut"]``), or one the
history test finds, keeping under :data:`CUT_HISTORY` of the pixels (that frame is then denoised
as a history's first, its exposure its own).  Non-finite model
output, should it happen, is replaced by the sanitised input and the state is reset.
"""
from __future__ import annotations

import os
import sys
import tempfile
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from mcdenoise.runtime import temporal, timing, transfer
from mcdenoise.runtime.contract import parse_contract
from mcdenoise.runtime.frames import Frame, FrameError
from mcdenoise.runtime.inputs import (RADIANCE_LAYERS, SanitizeReport, exposure_scale, frame_planes, from_planes,
                                     model_inputs, sample_inputs)
from mcdenoise.runtime.prelude import MAX_SLOTS, PreludeGraph, device_of, run_bound
from mcdenoise.runtime.temporal import Protocol
from mcdenoise.runtime.workers import MAX_DEFAULT_THREADS, default_threads

#: Guide layers stored for the consistency test, when the frame has them.
GUIDE_LAYERS = ("depth", "position", "normal")
#: A frame whose history test keeps less than this share of the pixels is an unflagged cut: the
#: 0.1% an unflagged cut of the stress test kept cost anf-s 2.3 dB, through the old exposure.
CUT_HISTORY = 0.02


class ModelFileError(ValueError):
    """The model file is missing, not ONNX, corrupt, or not an mcdenoise model."""


@dataclass
class Report:
    """What happened to the input so far: sanitised values, state resets, messages."""

    frames: int = 0
    sanitized_frames: int = 0
    negative_output_values: int = 0
    resets: list = field(default_factory=list)
    messages: list = field(default_factory=list)


def _as_frame(frame) -> Frame:
    if isinstance(frame, Frame):
        return frame
    if isinstance(frame, dict):
        if "color" not in frame:
            raise FrameError("frame: missing layer 'color'")
        known = {k: v for k, v in frame.items() if k in Frame.__dataclass_fields__}
        return Frame(**{k: (np.asarray(v, dtype=np.float32) if k not in ("meta", "path") else v)
                        for k, v in known.items()})
    if isinstance(frame, np.ndarray):
        return Frame(color=np.asarray(frame, dtype=np.float32))
    raise FrameError(f"frame: expected a Frame, a dict of layers or an (H, W, 3) array, got {type(frame).__name__}")


class Denoiser:
    """Stateful onnxruntime driver for one mcdenoise model file.  Not thread-safe."""

    def __init__(self, session, contract, path: str, log=None,
                 autoexposure: bool = True, driver_threads: int | None = None, prelude=None):
        self.session = session
        #: What reprojects and accumulates the history: None (numpy, runtime.temporal) or the
        #: prelude graph (:class:`runtime.prelude.PreludeGraph`), which computes the same.
        self.prelude = prelude
        #: Whether the history stays onnxruntime values on the model's device between frames
        #: (the prelude graph then gives them on the device: ``prelude.device``).
        self.io_binding = prelude is not None and prelude.device is not None
        self._device = device_of(session) if self.io_binding else None
        #: Threads of the driver's own numpy stages (layer conversion, reprojection).
        self.driver_threads = default_threads() if driver_threads is None else max(1, int(driver_threads))
        self.autoexposure = autoexposure
        #: The current history's auto-exposure factor (set at its first frame; 1 when off).
        self.exposure = 1.0
        self.contract = contract
        #: How the history is kept and fed back (one definition with the trainer's unroll).
        self.protocol = Protocol.from_contract(contract)
        self.path = path
        self._log = log if log is not None else (lambda msg: print(f"mcdenoise: {msg}", file=sys.stderr))
        self.report = Report()
        self.timings: list[dict[str, float]] = []
        #: (H, W) of each frame in ``timings``.
        self.frame_sizes: list[tuple[int, int]] = []
        self._said: set[str] = set()
        self._profile_rows: list | None = None
        self._state: dict[str, np.ndarray] | None = None
        self._guides: dict[str, np.ndarray] | None = None
        #: Reused input planes (:func:`runtime.inputs.frame_planes`), two sets, and the index
        #: of the set holding ``_guides``.
        self._plane_buffers: tuple[dict, dict] = ({}, {})
        self._guides_set = 0
        self._size: tuple[int, int] | None = None
        names = {i.name for i in session.get_inputs()}
        self.frame_layers = [i["layer"] for i in contract.inputs if i["name"] in names and i.get("layer")]
        self._input_name = {i["layer"]: i["name"] for i in contract.inputs if i.get("layer")}
        self._input_transfer = {i["layer"]: i.get("transfer", "linear") for i in contract.inputs if i.get("layer")}
        self.graph_stages = [s["name"] for s in contract.stages]
        #: Whether the frame's layers are converted by the prelude's graphs on the device.
        self._convert = self.io_binding and all(self._input_transfer[l] == "linear" for l in self.frame_layers)
        #: The per-sample input's groups (None for a pixel model).
        self._samples = contract.samples_input
        #: Run-time settings (int64 scalar inputs): name -> value; change with :meth:`set`.
        self.settings = {st["name"]: st["default"] for st in contract.settings}

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, path: str | os.PathLike, providers=None, threads: int = 0,
             profile: bool = False, log=None, autoexposure: bool = True,
             driver_threads: int | None = None, prelude: str = "auto",
             accumulate_alpha: float | None = None, history_spp: float | None = None,
             settings: dict | None = None, io_binding: bool | None = None) -> "Denoiser":
        """Open an mcdenoise ONNX file.

        Args:
          providers: onnxruntime execution providers (default: CPU).
          threads: intra-op threads (0: onnxruntime default).
          driver_threads: threads of the driver's numpy stages (None: ``threads`` when given, at
            most :data:`runtime.workers.MAX_DEFAULT_THREADS`, else :func:`runtime.workers.default_threads`).
          profile: record per-node times so :meth:`stage_table` can split the graph by stage.
          prelude: "numpy" reprojects and accumulates the history in numpy; "graph" with the
            prelude graphs (:mod:`runtime.prelude`) on the model's providers; "auto" (default):
            numpy on the CPU provider (faster there, README), the graphs on any other.
          accumulate_alpha: the current frame's weight in (0, 1] for every accumulated input and
            fed state weight instead of the file's (1: no accumulation; the file's history_spp
            rule is dropped unless ``history_spp`` is given too), the graph unchanged.
          history_spp: weigh a frame of known spp by spp / (spp + history_spp) instead of the
            file's rule (0: the fixed alpha); see :meth:`runtime.temporal.Protocol.alpha`.
          settings: run-time settings to start with (name -> value, see :meth:`set`).
          io_binding: keep the history, the frame's converted layers and the output as
            onnxruntime values on the model's device, bound with IO binding; only the frame's
            layers go in and the image comes out. None (default): on where the prelude graphs
            run on a provider other than the CPU's. The images are the same either way.
          autoexposure: scale each history's colour to :data:`runtime.inputs.AUTOEXPOSURE_KEY`
            (fixed at the history's first frame, so the state keeps one unit), the output back.
        Raises ModelFileError for a missing, corrupt or foreign file.
        """
        import onnxruntime as ort

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise ModelFileError(f"{path}: no such model file")
        so = ort.SessionOptions()
        if threads:
            so.intra_op_num_threads = threads
        so.log_severity_level = 3
        # Workers spinning after a run hold cores the driver's numpy stages need (the 720p
        # preprocess 24 -> 15 ms with this, wskpn-3, 2 threads, paired runs).
        so.add_session_config_entry("session.force_spinning_stop", "1")
        if profile:
            so.enable_profiling = True
            # else a failed load also logs "Could not write a profile" beside the ModelFileError
            so.log_severity_level = 4
            so.profile_file_prefix = os.path.join(tempfile.mkdtemp(prefix="mcdenoise-prof-"), "ort")
        try:
            with warnings.catch_warnings():
                # A provider this onnxruntime lacks is reported by the caller, in one line.
                warnings.filterwarnings("ignore", message=".*is not in available provider names.*")
                sess = ort.InferenceSession(path, so, providers=providers or ["CPUExecutionProvider"])
        except Exception as e:
            raise ModelFileError(f"{path}: not a loadable ONNX model ({str(e).splitlines()[0][:200]})") from None
        try:
            contract = parse_contract(sess.get_modelmeta().custom_metadata_map)
        except ValueError as e:
            raise ModelFileError(f"{path}: {e}") from None
        if contract.samples_input is not None:
            # onnxruntime's memory pattern is allocated beside the arena the first run filled
            # (ndle-s, 720p x 8 spp: 8.2 GB after two runs with it, 4.1 GB without, no slower).
            so.enable_mem_pattern = False
            sess = ort.InferenceSession(path, so, providers=providers or ["CPUExecutionProvider"])
        if driver_threads is None and threads:
            driver_threads = min(threads, MAX_DEFAULT_THREADS)
        if prelude not in ("auto", "graph", "numpy"):
            raise ValueError(f"prelude must be auto, graph or numpy, got {prelude!r}")
        graph = None
        on_device = sess.get_providers()[0] != "CPUExecutionProvider"
        io_binding = on_device and prelude != "numpy" if io_binding is None else bool(io_binding)
        if io_binding and prelude == "numpy":
            raise ValueError("io_binding keeps the history on the device: it needs prelude 'graph' or 'auto'")
        if io_binding or prelude == "graph" or (prelude == "auto" and on_device):
            graph = PreludeGraph(providers=sess.get_providers(), threads=threads,
                                 device=device_of(sess) if io_binding else None)
        if graph is not None and len(contract.state) + len(contract.accumulate) > MAX_SLOTS:
            raise ValueError(f"{path}: the prelude graphs keep at most {MAX_SLOTS} tensors; use prelude='numpy'")
        den = cls(sess, contract, path, log=log, autoexposure=autoexposure,
                  driver_threads=driver_threads, prelude=graph)
        if accumulate_alpha is not None and not 0 < accumulate_alpha <= 1:
            raise ValueError(f"accumulate_alpha must be in (0, 1], got {accumulate_alpha}")
        if history_spp is not None and not history_spp >= 0:
            raise ValueError(f"history_spp must be >= 0, got {history_spp}")
        if accumulate_alpha is not None or history_spp is not None:
            def rule(alpha, hs):   # the overrides, for accumulations and fed state weights alike
                return (alpha if accumulate_alpha is None else float(accumulate_alpha),
                        float(history_spp) if history_spp is not None else hs if accumulate_alpha is None else 0.0)
            den.protocol = replace(den.protocol,
                                   accumulate=tuple((l, i, *rule(a, hs)) for l, i, a, hs in den.protocol.accumulate),
                                   weights=tuple((i, *rule(a, hs)) for i, a, hs in den.protocol.weights))
        for name, value in (settings or {}).items():
            den.set(name, value)
        return den

    def set(self, name: str, value: int) -> None:
        """Change a run-time setting (e.g. ANF's ``kernel_size``) from the next frame on; the
        history is kept.  ValueError naming the allowed values otherwise."""
        st = next((st for st in self.contract.settings if st["name"] == name), None)
        if st is None:
            raise ValueError(f"{self.contract.spec_name} has no setting {name!r}; it has {list(self.settings)}")
        ok = isinstance(value, (int, np.integer)) and st["min"] <= value <= st["max"] and not (value - st["min"]) % st["step"]
        if not ok:
            raise ValueError(f"{name} must be one of {st['min']}, {st['min'] + st['step']}, ... {st['max']}, got {value!r}")
        self.settings[name] = int(value)

    # ------------------------------------------------------------------ state
    def reset(self, reason: str | None = None) -> None:
        """Drop the temporal state; the next frame starts a new history."""
        if self._state is not None and reason:
            self.report.resets.append((self.report.frames, reason))
            self._say(f"frame {self.report.frames}: {reason}: temporal state reset", once_key=None)
        self._state = None
        self._guides = None

    def _say(self, msg: str, once_key: str | None) -> None:
        if once_key is not None:
            if once_key in self._said:
                return
            self._said.add(once_key)
        self.report.messages.append(msg)
        self._log(msg)

    # ------------------------------------------------------------------ denoise
    def __call__(self, frame) -> np.ndarray:
        """Denoise one frame of the current sequence; returns (H, W, 3) float32 linear HDR."""
        tm = timing.FrameTimer()
        with tm.stage(timing.PREPROCESS):
            fr = _as_frame(frame)
            for layer in self.frame_layers:
                fr.layer(layer)  # FrameError naming the layer if absent
            if self._samples is not None and fr.samples is None:
                sample_inputs(fr, ())  # the FrameError saying what per-sample data is and how to get it
            fr.validate()                     # FrameError naming what is wrong
            h, w = fr.size
            if fr.color.ndim != 3 or fr.color.shape[2] != 3:
                raise FrameError(f"{fr.path or 'frame'}: color must be (H, W, 3), got {fr.color.shape}")
            if self._size is not None and (h, w) != self._size:
                self.reset(f"resolution changed from {self._size[1]}x{self._size[0]} to {w}x{h}")
            self._size = (h, w)
            if fr.meta.get("cut") and self._state is not None:
                self.reset("camera cut")
            rep = SanitizeReport()
            # Each layer is converted to planes and sanitised once, whether the model, the
            # guide buffers or the reprojection reads it.
            extra = [g for g in GUIDE_LAYERS if getattr(fr, g) is not None]
            if self.protocol.temporal and fr.motion is not None:
                extra.append("motion")
            # Two buffer sets: this frame fills the one the kept previous guides are not in
            # (also after a frame that failed half-way).
            buffer_set = 1 - self._guides_set
            # A history's exposure is fixed at its first frame; after that the colour is
            # scaled while it is converted (one pass fewer over it).
            exposed = {l: np.float32(self.exposure) for l in RADIANCE_LAYERS} \
                if self._state is not None and self.exposure != 1.0 else None
            # The colour sets the exposure and replaces a bad output even when the model reads only samples.
            layers = [*self.frame_layers, *(() if "color" in self.frame_layers else ("color",))]
            names = dict.fromkeys([*layers, *extra])
            if self._convert and self._state is not None:   # a history's first frame sets its exposure on the host
                planes, feeds_by_layer = self.prelude.convert(fr, names, layers, rep, self.exposure)
            else:
                planes = frame_planes(fr, names, rep, buffers=self._plane_buffers[buffer_set],
                                      threads=self.driver_threads, scale=exposed)
                feeds_by_layer = model_inputs(planes, layers, fr.meta)
            guides = self._guide_buffers(fr, planes)
            if self.io_binding:
                import onnxruntime as ort   # uploaded once; kept as the next frame's previous guides

                guides = {k: v if isinstance(v, ort.OrtValue) else
                          ort.OrtValue.ortvalue_from_numpy(np.ascontiguousarray(v), *self._device) for k, v in guides.items()}
            if self._state is None:
                # A new history: fix its exposure now, so the state stays in one unit.
                self.exposure = float(exposure_scale(feeds_by_layer["color"]).ravel()[0]) if self.autoexposure else 1.0
            feeds = {}
            for l, a in feeds_by_layer.items():
                if l in RADIANCE_LAYERS and self.exposure != 1.0 and exposed is None:
                    # In place: the planes are the driver's own buffers (frame_planes copies
                    # every layer), and a new 11 MB array costs its page faults (720p).
                    a = np.multiply(a, np.float32(self.exposure), out=a)
                if l in self._input_name:    # (values on the device: linear transfers only, see _convert)
                    feeds[self._input_name[l]] = a if not isinstance(a, np.ndarray) else \
                        transfer.get(self._input_transfer[l])(a).astype(np.float32, copy=False)
            if self._samples is not None:
                feeds[self._samples["name"]] = sample_inputs(fr, [g["group"] for g in self._samples["groups"]], rep,
                                                             None if self.exposure == 1.0 else self.exposure)
            feeds.update({st["input"]: np.array(self.settings[st["name"]], np.int64) for st in self.contract.settings})
            if rep.total:
                self.report.sanitized_frames += 1
                kinds = ",".join(sorted(set(rep.nonfinite) | set(rep.negative) | set(rep.clamped)))
                self._say(f"frame {self.report.frames}: sanitised input ({rep.summary()}); "
                          "further sanitising is counted in the report", once_key="sanitize:" + kinds)
        with tm.stage(timing.REPROJECT):
            accumulated, kept = self._state_inputs(planes.get("motion"), guides, h, w, feeds, fr.color_spp)
        if kept is not None and kept < CUT_HISTORY:
            self.reset(f"the history test kept {kept:.1%} of the pixels (an unflagged camera cut)")
            self.report.sanitized_frames -= bool(rep.total)     # counted again by the new history's frame
            return self(frame)
        with tm.stage(timing.GRAPH):
            if self.io_binding:
                named = run_bound(self.session, feeds, self._device, host=() if self._convert else ("output",))
            else:
                named = dict(zip([o.name for o in self.session.get_outputs()], self.session.run(None, feeds)))
        with tm.stage(timing.POSTPROCESS):
            inv = np.float32(1.0 / self.exposure)
            scale = None if inv == 1 else inv
            # Back to the caller's units (auto-exposure) in the same pass as the layout change
            # and the extrema (NaN/inf propagate); redone in the rare case they say it must be.
            ext: list = []
            if self._convert:     # on the device: only the image and [min, sum] come back
                image, ext = self.prelude.post(named["output"], inv)
            else:
                image = from_planes(named["output"][0], scale, threads=self.driver_threads, extrema=ext)
            lo, hi = ext
            if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0:
                out = (o if isinstance(o := named["output"], np.ndarray) else o.numpy())[0]   # (3, H, W)
            if not (np.isfinite(lo) and np.isfinite(hi)):
                bad = ~np.isfinite(out)
                color = feeds_by_layer["color"]                         # already exposure-scaled
                out = np.where(bad, (color if isinstance(color, np.ndarray) else color.numpy())[0], out)
                self._say(f"frame {self.report.frames}: model produced {int(bad.sum())} non-finite "
                          "values; replaced by the input and state reset", once_key=None)
                named = None
                lo = out.min()
            if lo < 0:
                # Radiance cannot be negative; multi-resolution blends (WSKPN Eq. 7) are not
                # convex and can undershoot at edges, so clamp and count it.
                neg = out < 0
                self._say(f"frame {self.report.frames}: model output had negative values; clamped to 0 "
                          "(counted in the report)", once_key="negative-output")
                self.report.negative_output_values += int(neg.sum())
                out = np.maximum(out, 0.0)
            if named is None or lo < 0:
                image = from_planes(out.astype(np.float32, copy=False), scale, threads=self.driver_threads)
        with tm.stage(timing.STATE_UPDATE):
            if named is None:
                self._state, self._guides = None, None
            else:
                self._state = self.protocol.update(accumulated, named, keep=self._keep)
                self._guides, self._guides_set = guides, buffer_set
        tm.ms[timing.TOTAL] = sum(v for k, v in tm.ms.items())
        self.timings.append(tm.ms)
        self.frame_sizes.append((h, w))
        self.report.frames += 1
        return image

    def _guide_buffers(self, fr: Frame, planes: dict) -> dict[str, np.ndarray]:
        g = {name: planes[name] for name in GUIDE_LAYERS if name in planes}
        if "depth" not in g:
            # Without depth there is no consistency test: treat every pixel as a hit at unit
            # distance so history follows motion only (documented for plain colour input).
            g["depth"] = np.ones((1, 1, *fr.size), np.float32)
        return g

    @staticmethod
    def _keep(arr: np.ndarray) -> np.ndarray:
        """A state output as the history keeps it: float32, non-finite values 0 (they must never
        reach the next frame; one kept on the device as an onnxruntime value is kept as it is,
        and the prelude graph reads its non-finite values as 0)."""
        if not isinstance(arr, np.ndarray):
            return arr
        arr = arr.astype(np.float32, copy=False)
        if not (np.isfinite(arr.min()) and np.isfinite(arr.max())):
            arr = np.where(np.isfinite(arr), arr, np.float32(0.0))
        return arr

    def _state_inputs(self, motion, guides, h: int, w: int, feeds: dict, spp: int = 0) -> tuple[dict, float | None]:
        """The protocol's feeds for this frame (:class:`runtime.temporal.Protocol`): a new
        history's zeros, or the kept one reprojected; returns (the accumulations to keep, the
        share of pixels the history test kept, None on a history's first frame). ``motion``
        (1, 2, H, W) sanitised (non-finite -> 0) or None; ``feeds`` this frame's (sanitised)
        inputs; ``spp`` its samples per pixel (0: unknown), for a weight that depends on it."""
        if not self.protocol.temporal:
            return {}, None
        if self._state is None:
            return self.protocol.start(feeds, next(iter(feeds.values())), spp), None
        if motion is None:
            self._say("frames carry no motion vectors: assuming a static camera", once_key="nomotion")
            motion = np.zeros((1, 2, h, w), np.float32)
        seen = []    # the history mask, for the share of pixels it keeps

        def reproject_fn(*args, **kw):
            warped, history = (self.prelude or temporal.reproject)(*args, **kw)
            seen.append(history)
            return warped, history
        kept = self.protocol.follow(feeds, self._state, motion, guides, self._guides,
                                    contiguous=lambda a: np.ascontiguousarray(a, np.float32) if isinstance(a, np.ndarray) else a,
                                    reproject_fn=reproject_fn, threads=self.driver_threads, spp=spp)
        return kept, float(np.mean(h if isinstance(h := seen[0], np.ndarray) else h.numpy()))

    # ------------------------------------------------------------------ timing
    def stage_times(self) -> list[dict[str, float]]:
        """Per-frame {stage: ms}: driver stages, graph stages (if profiling), graph wall, total.

        With profiling on this ends the profiler (call once, after the sequence)."""
        rows = [dict(r) for r in self.timings]
        if self.session.get_session_options().enable_profiling:
            if self._profile_rows is None:
                path = self.session.end_profiling()
                self._profile_rows = timing.graph_stage_times(path, self.graph_stages)
            for row, g in zip(rows, self._profile_rows):
                row.update(g)
        return rows

    def timed_frames(self, skip: int = 1) -> tuple[list[dict[str, float]], tuple[int, int] | None, int]:
        """The per-frame stage times (:meth:`stage_times`) that one median should pool: after
        the first ``skip`` frames (warm-up; all frames if there are no more), those at the
        resolution most of them ran at (ties: the one seen last), because a median over two
        resolutions describes neither.  Returns (rows, (H, W) or None before any frame, how
        many frames at other resolutions were left out)."""
        rows = self.stage_times()
        use = list(range(len(rows)))
        use = use[skip:] if len(use) > skip else use
        if not use:
            return [], self._size, 0
        sizes = [self.frame_sizes[i] for i in use]
        size = max(set(sizes), key=lambda s: (sizes.count(s), max(j for j, t in enumerate(sizes) if t == s)))
        kept = [rows[i] for i, s in zip(use, sizes) if s == size]
        return kept, size, len(use) - len(kept)

    def stage_table(self, skip: int = 1, device: str | None = None) -> str:
        """Paper-style table of median per-stage ms (first ``skip`` frames are warm-up; frames
        at other resolutions than most, see :meth:`timed_frames`, are left out and counted)."""
        use, size, other = self.timed_frames(skip)
        med = timing.medians(use)
        h, w = size or (0, 0)
        resolution = f"{w}x{h}"
        if other:
            resolution += f" ({other} frame{'s' if other > 1 else ''} at other sizes left out)"
        order = list(timing.DRIVER_STAGES_BEFORE) + self.graph_stages + list(timing.DRIVER_STAGES_AFTER)
        title = f"{self.contract.spec_name}: per-stage time"
        if device is None:
            provider = self.session.get_providers()[0]
            device = timing.cpu_name() if provider == "CPUExecutionProvider" else provider
        return timing.format_table(med, order, self.contract.paper, resolution, title, len(use), device)
