"""The temporal prelude as onnxruntime graphs, one per count K of kept tensors (exported by
``mcdenoise.export.prelude`` from the torch path of :func:`runtime.temporal.reproject`): the
arithmetic the driver runs in numpy, for a provider that keeps frames on its device.
:class:`PreludeGraph` has ``reproject``'s signature (so :meth:`runtime.temporal.Protocol.follow`
takes it) and takes and gives host arrays or onnxruntime values on the device
(:func:`run_bound`), so a history need not leave the device between frames."""
from __future__ import annotations

import numpy as np

from mcdenoise.runtime import data_path
from mcdenoise.runtime.inputs import NONFINITE_FILL, RADIANCE_LAYERS, camera_axes
from mcdenoise.runtime.temporal import reproject

#: Kept tensors (state and accumulated inputs) the shipped graphs take: one graph per count.
MAX_SLOTS = 4
#: The K-slot graph's file name.
SLOT_FILE = "prelude-{}.onnx"
#: The frame's input conversion graphs (mcdenoise.export.prelude says what they compute).
CONVERT_FILE, SCREEN_FILE, POST_FILE = "convert.onnx", "screen.onnx", "post.onnx"
#: Guide inputs, after ``prev<i>``, ``current<i>``, ``alpha``, ``blend``, ``motion``.
GUIDES = ("cur_depth", "cur_position", "cur_normal", "prev_depth", "prev_position", "prev_normal")


def inputs(k: int) -> tuple[str, ...]:
    """Input names of the K-slot graph, in order (mcdenoise.export.prelude says what they are)."""
    return (*(f"prev{i}" for i in range(k)), *(f"current{i}" for i in range(k)), "alpha", "blend", "motion", *GUIDES)


def outputs(k: int) -> tuple[str, ...]:
    return (*(f"warped{i}" for i in range(k)), "history")


def device_of(session) -> tuple[str, int]:
    """(onnxruntime device type, id) where ``session``'s first provider keeps its values."""
    provider = session.get_providers()[0]
    if provider == "CPUExecutionProvider":
        return "cpu", 0
    opts = session.get_provider_options().get(provider, {})
    return provider.replace("ExecutionProvider", "").lower(), int(opts.get("device_id", 0))


def run_bound(session, feeds: dict, device: tuple[str, int] | None, host: tuple = ()) -> dict:
    """``session`` run with IO binding: ``feeds`` host arrays (copied to the device by
    onnxruntime) or ``OrtValue``s (bound as they are); outputs stay on ``device`` as
    ``OrtValue``s, except those named in ``host`` (and all when ``device`` is None), which come
    back as numpy arrays. Returns {output name: value}."""
    import onnxruntime as ort

    b = session.io_binding()
    for name, v in feeds.items():
        if isinstance(v, ort.OrtValue):
            b.bind_ortvalue_input(name, v)
        else:
            b.bind_cpu_input(name, np.ascontiguousarray(v, np.float32) if v.dtype != np.int64 else v)
    for name in (names := [o.name for o in session.get_outputs()]):
        b.bind_output(name, *(("cpu",) if device is None or name in host else device))
    session.run_with_iobinding(b)
    return {n: (v.numpy() if device is None or n in host else v) for n, v in zip(names, b.get_outputs())}


class PreludeGraph:
    """``reproject(states, motion, cur, prev, blend=...)`` run by onnxruntime on ``providers``;
    with ``device`` (a :func:`device_of` pair) the warped states and the history stay there as
    ``OrtValue``s, else they come back as numpy arrays. Frames without world positions or
    normals (the graphs test both) go to the numpy path."""

    def __init__(self, folder=None, providers=None, threads: int = 0, device: tuple[str, int] | None = None):
        self.folder = folder or data_path("models", "driver")
        self.providers = providers or ["CPUExecutionProvider"]
        self.threads, self.device = threads, device
        self.sessions: dict[int, object] = {}

    def session(self, k):
        """The K-slot graph's session (``k`` an int), or the conversion graph named ``k``."""
        if isinstance(k, int) and not 1 <= k <= MAX_SLOTS:
            raise ValueError(f"the prelude graphs keep 1 to {MAX_SLOTS} tensors; this model keeps {k}")
        if k not in self.sessions:
            import onnxruntime as ort

            so = ort.SessionOptions()
            so.log_severity_level = 3
            so.add_session_config_entry("session.force_spinning_stop", "1")   # as the model's (denoiser.py)
            if self.threads:
                so.intra_op_num_threads = self.threads
            name = SLOT_FILE.format(k) if isinstance(k, int) else k
            self.sessions[k] = ort.InferenceSession(str(self.folder / name), so, providers=self.providers)
        return self.sessions[k]

    def convert(self, frame, names, layers, report, scale: float = 1.0) -> tuple[dict, dict]:
        """:func:`runtime.inputs.frame_planes` of ``names`` (radiance layers times ``scale``, the
        counts into ``report``) and :func:`runtime.inputs.model_inputs` of ``layers``, by the
        conversion graphs on the device: (planes, inputs), name -> (1, C, H, W) values there
        (``OrtValue``s; numpy arrays without a device). Only the layers as the frame holds them
        go in, and only the counts come back."""
        import onnxruntime as ort

        dev = self.device or ("cpu", 0)
        planes = {}
        for name in names:
            x = ort.OrtValue.ortvalue_from_numpy(np.ascontiguousarray(frame.layer(name), np.float32), *dev)
            rad = name in RADIANCE_LAYERS
            flags = {"fill": NONFINITE_FILL.get(name, 0.0), "radiance": float(rad), "scale": scale if rad else 1.0}
            out = run_bound(self.session(CONVERT_FILE), {"x": x, **{k: np.array([v], np.float32) for k, v in flags.items()}},
                            self.device, host=("counts",))
            for counts, n in zip((report.nonfinite, report.negative, report.clamped), out["counts"].tolist()):
                if n:
                    counts[name] = counts.get(name, 0) + int(n)
            planes[name] = out["planes"]
        inputs = {name: planes[name] for name in layers}
        axes = camera_axes(frame.meta)
        if "normal" in inputs and axes is not None:
            inputs["normal"] = run_bound(self.session(SCREEN_FILE), {"normal": planes["normal"], "axes": axes},
                                         self.device)["screen"]
        return planes, inputs

    def post(self, output, scale) -> tuple[np.ndarray, list]:
        """The model's ``output`` (1, 3, H, W) on the device as the caller's (H, W, 3) image times
        ``scale`` (float32), by the post graph, with [its minimum, its sum] (the sum is
        non-finite when a value is; :func:`runtime.inputs.from_planes`' extrema say the same)."""
        out = run_bound(self.session(POST_FILE), {"output": output, "scale": np.array([scale], np.float32)}, None)
        return out["image"], [float(v) for v in out["checks"]]

    def __call__(self, states, motion, cur: dict, prev: dict, blend=None, threads: int = 1):
        guides = ("depth", "position", "normal")
        if not all(g in cur and g in prev for g in guides):
            # Kept on the device: fetched, non-finite -> 0 as the graphs read them.
            host = lambda a: a if isinstance(a, np.ndarray) else np.nan_to_num(a.numpy(), nan=0.0, posinf=0.0, neginf=0.0)  # noqa: E731
            blend = None if blend is None else [b if b is None else (host(b[0]), *b[1:]) for b in blend]
            return reproject([host(s) for s in states], host(motion), {g: host(v) for g, v in cur.items()},
                             {g: host(v) for g, v in prev.items()}, threads=threads, blend=blend)
        k = len(states)
        blend = list(blend) if blend is not None else [None] * k
        feeds = {**{f"prev{i}": s for i, s in enumerate(states)},
                 # model state's "current" is never read (blend 0), but must broadcast
                 **{f"current{i}": np.zeros((1, 1, 1, 1), np.float32) if b is None else b[0]
                    for i, b in enumerate(blend)},
                 "alpha": np.array([0.0 if b is None else b[1] for b in blend], np.float32),
                 "blend": np.array([0.0 if b is None else 1.0 for b in blend], np.float32), "motion": motion,
                 **{f"cur_{g}": cur[g] for g in guides}, **{f"prev_{g}": prev[g] for g in guides}}
        out = run_bound(self.session(k), feeds, self.device)
        return [out[f"warped{i}"] for i in range(k)], out["history"]
