"""Rendering one sequence into frame files.

Per frame t, with S samples per pixel:

* S passes at 1 spp, each with its own seed (and, with motion blur, its own shutter time
  tau_s in [0, 1): the sensor sits at the path's pose at u = t + tau_s).  Each pass is two
  Mitsuba renders with the same seed and sensor: ``path`` for radiance and ``aov`` (albedo,
  sh_normal, position, shape_index) for the guides.  With the same seed both trace the same
  primary rays; that is also all Mitsuba 3.9's ``aov`` integrator does when it wraps ``path``
  (it renders the inner integrator in a separate pass and then runs it again inside its own),
  so two calls cost about a third less than the wrapped one for identical output.  The film
  uses a box filter so a pixel's value is its one sample.  depth is the distance from the
  camera (lens) centre to the position.
* material features from the per-shape table (:mod:`materials`) through ``shape_index``;
* motion: the hit point X projected with the pose at u - 1 minus X projected with its own
  pose (not the pixel centre, which cancels the sample jitter); valid where X is a hit, lands
  on screen and in front of the previous camera, and a shadow ray from the previous camera
  centre reaches X unblocked;
* coc from X's camera depth; time tau_s;
* the reference: ``path`` at ref_spp with an independent seed (split over 16 shutter times
  with motion blur, so it is blurred like the input).

Pixel layers come from :func:`runtime.frames.pixel_means`; the pixel motion is the mean over
samples that hit something, and a pixel is valid only when all its samples are.
"""
from __future__ import annotations

import json
import os
import sys
import time as _time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from mcdenoise.runtime.frames import SAMPLE_FEATURES, SAMPLE_GROUPS, Frame, frame_name, pixel_means
from mcdenoise.runtime.writers import write_frame
from mcdenoise.training.render import camera as cam
from mcdenoise.training.render import materials, procedural

#: AOV integrator channels, in the order Mitsuba returns them after the RGB channels.  No
#: ``depth``: Mitsuba measures it from the near-clip plane (rays start there), so the renderer
#: takes the distance from the camera centre to ``position`` instead.
AOVS = "albedo:albedo,nn:sh_normal,pp:position,si:shape_index"
_AOV_WIDTH = 3 + 3 + 3 + 1
#: Shutter strata of a motion-blurred reference (each a separate render at its own time).
REF_TIME_STRATA = 16
#: A shadow ray from the previous camera counts X as visible when nothing is hit before
#: (1 - VIS_REL) of the distance minus VIS_ABS scene units (float32 hit points are ~1e-6
#: relative; this is loose enough for them and tight enough for contact shadows).
VIS_REL = 1e-3
VIS_ABS = 1e-4
#: Where a sequence keeps its scene export (a subfolder, so the scene's EXR textures never sit
#: beside the frames).
SCENE_DIR = "scene"


class RenderError(ValueError):
    """Rendering a sequence failed; the message names the sequence (and frame) and is one line,
    so ``mcdenoise render`` reports it without a traceback."""


def one_line(e: BaseException) -> str:
    """An exception as one line: Mitsuba's messages span several lines and end with the cause."""
    lines = [ln.strip() for ln in str(e).strip().splitlines() if ln.strip()]
    return lines[-1] if lines else type(e).__name__


def shape_bounds(shape) -> tuple[np.ndarray, np.ndarray]:
    """World-space (min, max) (3,) float64 of a shape's geometry.

    Meshes are bounded by their vertices rather than ``shape.bbox()``: Mitsuba 3.9's scene
    loader (``optimize=True``, the default of ``load_dict``/``load_file``) merges meshes that
    share an equivalent BSDF into one mesh with an empty id, and that merged mesh's ``bbox()``
    is the bounding box of only one of its parts.
    """
    if shape.is_mesh() and shape.vertex_count() > 0:
        v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
        return v.min(axis=0), v.max(axis=0)
    b = shape.bbox()
    return np.asarray(b.min, np.float64).reshape(-1), np.asarray(b.max, np.float64).reshape(-1)


@dataclass
class Sequence:
    """Everything needed to render one sequence.

    name: folder name; seed: scene seed; scene: the loaded ``mi.Scene``; intrinsics, path: the
    camera; frames: number of frames; defocus, motion_blur: effect flags; source: "procedural"
    or the user's scene file; max_depth: path depth; info: extra manifest fields.
    """

    name: str
    seed: int
    scene: object
    intrinsics: cam.Intrinsics
    path: cam.CameraPath
    frames: int
    defocus: bool
    motion_blur: bool
    source: str
    max_depth: int = procedural.MAX_DEPTH
    info: Optional[dict] = None


def ref_strata(ref_spp: int, motion_blur: bool) -> int:
    """Render calls for one reference: one per shutter stratum with motion blur, else one."""
    return min(ref_spp, REF_TIME_STRATA) if motion_blur else 1


def passes_per_frame(spp: int, ref_spp: int, motion_blur: bool) -> int:
    """Render calls per frame, as counted by ``render_frame``'s progress callback."""
    return spp + ref_strata(ref_spp, motion_blur)


def derive_seed(*words: int) -> int:
    """A uint32 render seed from integers (scene seed, frame, stream, index): independent
    streams for passes and references, stable across runs and platforms."""
    return int(np.random.SeedSequence([int(w) for w in words]).generate_state(1)[0])


# ----------------------------------------------------------------------------------------------
# Loading scenes
# ----------------------------------------------------------------------------------------------

_TRANSFORM_KEYS = ("to_world", "to_uv")


def to_mitsuba(mi, desc: dict, folder: str | None = None) -> dict:
    """A JSON-able scene dict (4x4 lists for transforms, relative file names) -> a dict for
    ``mi.load_dict``: transforms become ``ScalarTransform4f``, file names are joined to ``folder``."""
    out = {}
    for k, v in desc.items():
        if isinstance(v, dict):
            out[k] = to_mitsuba(mi, v, folder)
        elif k in _TRANSFORM_KEYS and isinstance(v, list):
            out[k] = mi.ScalarTransform4f(np.asarray(v, np.float64).tolist())
        elif k == "filename" and folder is not None and not os.path.isabs(v):
            out[k] = os.path.join(folder, v)
        else:
            out[k] = v
    return out


def write_scene_xml(mi, desc: dict, path: str) -> None:
    """Write a scene dict as Mitsuba XML (file names stay relative to the XML's folder)."""
    cfg = mi.parser.ParserConfig(mi.variant())
    state = mi.parser.parse_dict(cfg, to_mitsuba(mi, desc))
    with open(path, "w") as fh:
        fh.write(mi.parser.write_string(state))


def load_procedural(mi, spec: procedural.SceneSpec, folder: str, frames: int, spp: int) -> Sequence:
    """Export the procedural scene into ``folder/scene/`` (meshes, textures, ``scene.json``,
    ``scene.xml``, ``camera_path.json``) and load it from there."""
    scene_dir = os.path.join(folder, SCENE_DIR)
    procedural.write_assets(spec, scene_dir)
    keys = spec.path.key_frames(frames)
    desc = procedural.scene_description(spec, keys[0], spp)
    with open(os.path.join(scene_dir, "scene.json"), "w") as fh:
        json.dump(desc, fh, indent=1)
    write_scene_xml(mi, desc, os.path.join(scene_dir, "scene.xml"))
    cam.save_camera_path(os.path.join(scene_dir, "camera_path.json"), keys, spec.intrinsics)
    scene = mi.load_dict(to_mitsuba(mi, {k: v for k, v in desc.items() if k not in ("sensor", "integrator")},
                                     scene_dir))
    return Sequence(name=spec.name, seed=spec.seed, scene=scene, intrinsics=spec.intrinsics, path=spec.path,
                    frames=frames, defocus=spec.defocus, motion_blur=spec.motion_blur, source="procedural",
                    info={"setting": spec.setting, "shapes": len(scene.shapes())})


def _matrix(value) -> np.ndarray:
    return np.asarray(value.matrix if hasattr(value, "matrix") else value, np.float64).reshape(4, 4)


def _scalar(params, key: str, default: float) -> float:
    return float(np.asarray(params[key]).reshape(-1)[0]) if key in params else default


def user_scene(mi, xml: str, size: tuple[int, int], seed: int, frames: int | None,
               camera_path: str | None = None, speed: float = 1.0,
               motion_blur: bool = False) -> Sequence:
    """A user's Mitsuba scene file with a camera path: the key frames of ``camera_path``
    (JSON, :func:`camera.load_camera_path`) or, without one, a random drift and turn around the
    file's first sensor, deterministic from ``seed``.  The sensor's field of view and lens are
    kept; film, filter and sampler are replaced by the renderer's.
    """
    xml = os.fspath(xml)
    if not os.path.isfile(xml):
        raise FileNotFoundError(f"{xml}: scene file not found")
    try:
        scene = mi.load_file(xml)
    except Exception as e:  # Mitsuba raises RuntimeError/ValueError with multi-line messages
        raise ValueError(f"{xml}: Mitsuba cannot load this scene: {str(e).strip().splitlines()[-1]}") from None
    width, height = size
    base_intr = {"x_fov": 45.0, "near_clip": 0.01, "far_clip": 1e4, "aperture_radius": 0.0, "focus_distance": 1.0}
    base = None
    if scene.sensors():
        sensor = scene.sensors()[0]
        kind = materials.class_name(repr(sensor))
        if kind not in ("PerspectiveCamera", "ThinLensCamera"):
            raise ValueError(f"{xml}: sensor type {kind} is not supported (use perspective or thinlens)")
        p = mi.traverse(sensor)
        if abs(_scalar(p, "principal_point_offset_x", 0.0)) > 0 or abs(_scalar(p, "principal_point_offset_y", 0.0)) > 0:
            raise ValueError(f"{xml}: sensors with a principal point offset are not supported")
        base = _matrix(p["to_world"])
        base_intr.update(x_fov=_scalar(p, "x_fov", 45.0), near_clip=_scalar(p, "near_clip", 0.01),
                         far_clip=_scalar(p, "far_clip", 1e4))
        if kind == "ThinLensCamera":
            base_intr.update(aperture_radius=_scalar(p, "aperture_radius", 0.0),
                             focus_distance=_scalar(p, "focus_distance", 1.0))
    if camera_path is not None:
        path, overrides = cam.load_camera_path(camera_path)
        unknown = set(overrides) - set(base_intr) - {"width", "height"}
        if unknown:
            raise ValueError(f"{camera_path}: unknown intrinsics {sorted(unknown)}")
        base_intr.update({k: float(v) for k, v in overrides.items() if k in base_intr})
        if frames is None:
            frames = len(path)
        elif frames > len(path):
            raise ValueError(f"{camera_path}: has {len(path)} frames, --frames asks for {frames}")
    else:
        if base is None:
            raise ValueError(f"{xml}: the scene has no sensor; add one or pass --camera-path")
        bbox = scene.bbox()
        diag = float(np.linalg.norm(np.asarray(bbox.max, np.float64).reshape(-1) - np.asarray(bbox.min, np.float64).reshape(-1)))
        rng = np.random.default_rng([seed, 2])
        vel = rng.normal(size=3)
        vel *= diag * rng.uniform(0.002, 0.01) * speed / np.linalg.norm(vel)
        axis = rng.normal(size=3) * np.array([0.3, 1.0, 0.15])  # mostly pan, some tilt, little roll
        path = cam.Relative(base=tuple(map(tuple, base)), velocity=tuple(vel), axis=tuple(axis),
                            omega=float(rng.uniform(0.3, 2.0) * speed * (1 if rng.random() < 0.5 else -1)))
        frames = 8 if frames is None else frames
    intr = cam.Intrinsics(width, height, **base_intr)
    name = f"{os.path.splitext(os.path.basename(xml))[0]}_{seed:07d}"
    if not scene.emitters():
        print(f"mcdenoise render: warning: {xml} has no emitters; frames will be black", file=sys.stderr)
    return Sequence(name=name, seed=seed, scene=scene, intrinsics=intr, path=path, frames=frames,
                    defocus=intr.thin_lens, motion_blur=motion_blur, source=os.path.abspath(xml),
                    info={"shapes": len(scene.shapes())})


# ----------------------------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------------------------

class SequenceRenderer:
    """Renders the frames of one :class:`Sequence` (see the module docstring).

    spp: samples per pixel stored per sample (S >= 1); ref_spp: reference samples (>= 1);
    variant: recorded in the frames' metadata.
    """

    def __init__(self, mi, seq: Sequence, spp: int, ref_spp: int, variant: str):
        if spp < 1 or ref_spp < 1:
            raise ValueError(f"spp and ref_spp must be >= 1, got {spp} and {ref_spp}")
        self.mi, self.seq, self.spp, self.ref_spp, self.variant = mi, seq, spp, ref_spp, variant
        intr = seq.intrinsics
        self.sensor = mi.load_dict(intr.sensor_dict(mi.ScalarTransform4f(seq.path.to_world(0.0).tolist())))
        self.sensor_params = mi.traverse(self.sensor)
        self.path_integrator = mi.load_dict({"type": "path", "max_depth": int(seq.max_depth)})
        self.aov_integrator = mi.load_dict({"type": "aov", "aovs": AOVS})
        self.lut, self.ids, self.names = materials.material_table(mi, seq.scene)
        self._bboxes = {int(i): shape_bounds(s) for i, s in zip(self.ids, seq.scene.shapes())}

    def set_pose(self, to_world: np.ndarray) -> None:
        """Move the sensor (no kernel recompilation: the transform is a parameter)."""
        self.sensor_params["to_world"] = self.mi.ScalarTransform4f(np.asarray(to_world, np.float64).tolist())
        self.sensor_params.update()

    def render_pass(self, to_world: np.ndarray, seed: int) -> dict:
        """One 1-spp pass at ``to_world``: radiance (H,W,3), albedo (H,W,3), normal (H,W,3),
        depth (H,W,1) (distance from the camera centre), position (H,W,3) float32 and shape
        ids (H,W) int64 (0 on a miss)."""
        mi = self.mi
        self.set_pose(to_world)
        rad = np.asarray(mi.render(self.seq.scene, sensor=self.sensor, integrator=self.path_integrator,
                                   spp=1, seed=seed), np.float32)
        aov = np.asarray(mi.render(self.seq.scene, sensor=self.sensor, integrator=self.aov_integrator,
                                   spp=1, seed=seed), np.float32)
        if rad.shape[-1] < 3 or aov.shape[-1] < _AOV_WIDTH:
            raise RuntimeError(f"unexpected Mitsuba output channels: path {rad.shape}, aov {aov.shape}")
        a = aov[..., -_AOV_WIDTH:]
        shape = np.rint(a[..., 9]).astype(np.int64)
        position = a[..., 6:9]
        depth = np.linalg.norm(position.astype(np.float64) - np.asarray(to_world)[:3, 3], axis=-1)
        depth = np.where(shape > 0, depth, 0.0).astype(np.float32)[..., None]
        return {"radiance": rad[..., :3], "albedo": a[..., 0:3], "normal": a[..., 3:6], "depth": depth,
                "position": position, "shape": shape}

    def check_shape_ids(self, shape: np.ndarray, position: np.ndarray) -> None:
        """Every hit's position must lie in the bounding box of the shape its id names; a failure
        means the shape_index -> shape mapping is wrong and material features would be too."""
        if shape.max(initial=0) >= len(self.lut) or shape.min(initial=0) < 0:
            raise RuntimeError(f"shape_index AOV values {shape.min()}..{shape.max()} outside the scene's "
                               f"shape ids {sorted(self._bboxes)}")
        for sid in np.unique(shape):
            if sid == 0:
                continue
            if int(sid) not in self._bboxes:
                raise RuntimeError(f"shape_index {sid} is not one of the scene's shape ids {sorted(self._bboxes)}")
            lo, hi = self._bboxes[int(sid)]
            pts = position[shape == sid]
            tol = 1e-3 * (1.0 + np.abs(np.concatenate([lo, hi])).max())
            if np.any(pts < lo - tol) or np.any(pts > hi + tol):
                name = self.names[list(self.ids).index(sid)] or "(a merged mesh)"
                raise RuntimeError(f"shape_index {sid} hits lie outside shape {name!r}: "
                                   f"the shape id mapping of this Mitsuba variant differs from the expected one")

    def visible_from(self, origin: np.ndarray, points: np.ndarray) -> np.ndarray:
        """bool (N,): a ray from ``origin`` (3,) reaches each of ``points`` (N, 3) unblocked."""
        mi = self.mi
        d = points - origin
        dist = np.linalg.norm(d, axis=1)
        ok = dist > 1e-6
        d = d / np.maximum(dist, 1e-12)[:, None]
        maxt = dist * (1.0 - VIS_REL) - VIS_ABS
        blocked = np.zeros(len(points), bool)
        if not len(points):
            return blocked
        if mi.variant().startswith("scalar"):
            scene, o = self.seq.scene, origin.tolist()
            for i in np.flatnonzero(maxt > 0):
                blocked[i] = scene.ray_test(mi.Ray3f(o, d[i].tolist(), float(maxt[i]), 0.0, mi.Color0f()))
        else:
            n = len(points)
            o = np.broadcast_to(origin.astype(np.float32)[:, None], (3, n))
            ray = mi.Ray3f(mi.Point3f(np.ascontiguousarray(o)), mi.Vector3f(np.ascontiguousarray(d.T, np.float32)),
                           mi.Float(np.maximum(maxt, 0.0).astype(np.float32)), mi.Float(0.0), mi.Color0f())
            blocked = np.asarray(self.seq.scene.ray_test(ray), bool).reshape(-1) & (maxt > 0)
        return ok & ~blocked

    def pass_times(self, t: int) -> np.ndarray:
        """Shutter times (S,) in [0, 1): stratified and jittered with motion blur, else 0."""
        if not self.seq.motion_blur:
            return np.zeros(self.spp)
        rng = np.random.default_rng([self.seq.seed, t, 7])
        return (np.arange(self.spp) + rng.random(self.spp)) / self.spp

    def reference(self, t: int, stream: int = 1, progress: Callable[[int], None] | None = None) -> tuple[np.ndarray, list]:
        """Reference radiance (H, W, 3) of frame t at ref_spp, and the seeds used.  ``stream``
        selects an independent set of seeds (1 is the stored reference)."""
        mi = self.mi
        k = ref_strata(self.ref_spp, self.seq.motion_blur)
        counts = [self.ref_spp // k + (1 if i < self.ref_spp % k else 0) for i in range(k)]
        if self.seq.motion_blur:
            rng = np.random.default_rng([self.seq.seed, t, 8, stream])
            times = (np.arange(k) + rng.random(k)) / k
        else:
            times = np.zeros(k)
        acc = np.zeros((self.seq.intrinsics.height, self.seq.intrinsics.width, 3), np.float64)
        seeds = []
        for i, (n, tau) in enumerate(zip(counts, times)):
            seed = derive_seed(self.seq.seed, t, 1000 + stream, i)
            seeds.append(seed)
            self.set_pose(self.seq.path.to_world(t + tau))
            img = np.asarray(mi.render(self.seq.scene, sensor=self.sensor, integrator=self.path_integrator,
                                       spp=n, seed=seed), np.float64)
            acc += img[..., :3] * n
            if progress:
                progress(1)
        return (acc / self.ref_spp).astype(np.float32), seeds

    def render_frame(self, t: int, progress: Callable[[int], None] | None = None) -> Frame:
        """Frame t with per-sample data, pixel layers, reference and metadata."""
        seq, intr = self.seq, self.seq.intrinsics
        h, w, s_count = intr.height, intr.width, self.spp
        g = SAMPLE_GROUPS
        samples = np.zeros((s_count, h, w, len(SAMPLE_FEATURES)), np.float32)
        valid = np.ones((h, w), bool) if t > 0 else np.zeros((h, w), bool)
        motion_sum = np.zeros((h, w, 2))
        hits = np.zeros((h, w))
        times = self.pass_times(t)
        seeds = []
        for s in range(s_count):
            u = t + float(times[s])
            pose = seq.path.to_world(u)
            seed = derive_seed(seq.seed, t, 0, s)
            seeds.append(seed)
            p = self.render_pass(pose, seed)
            shape = p["shape"]
            if s == 0:
                self.check_shape_ids(shape, p["position"])
            hit = shape > 0
            x = samples[s]
            for key in ("radiance", "albedo", "normal", "depth", "position"):
                x[..., g[key]] = p[key]
            rows = self.lut[shape]
            col = 0
            for key in materials.ROW:
                width = g[key].stop - g[key].start
                x[..., g[key]] = rows[..., col:col + width]
                col += width
            pos = p["position"].astype(np.float64)
            xy_own, z_own = cam.project(pos, pose, intr)
            x[..., g["coc"]] = np.where(hit, cam.coc_pixels(z_own, intr), 0.0)[..., None]
            x[..., g["time"]] = times[s]
            if t > 0:
                prev = seq.path.to_world(u - 1.0)
                xy_prev, z_prev = cam.project(pos, prev, intr)
                mv = np.where(hit[..., None], xy_prev - xy_own, 0.0)
                x[..., g["motion"]] = mv
                motion_sum += mv
                on_screen = (hit & (z_prev > intr.near_clip) & (xy_prev[..., 0] >= 0) & (xy_prev[..., 0] < w)
                             & (xy_prev[..., 1] >= 0) & (xy_prev[..., 1] < h))
                vis = np.zeros((h, w), bool)
                vis[on_screen] = self.visible_from(prev[:3, 3], pos[on_screen])
                valid &= vis
            hits += hit
            if progress:
                progress(1)
        reference, ref_seeds = self.reference(t, progress=progress)
        px = pixel_means(samples)
        motion = (motion_sum / np.maximum(hits, 1)[..., None]).astype(np.float32)
        to_world = seq.path.to_world(float(t))
        meta = {
            "scene_seed": seq.seed, "scene": seq.name, "frame": t, "frames": seq.frames,
            "spp": s_count, "ref_spp": self.ref_spp, "variant": self.variant, "cut": t == 0,
            "motion_blur": seq.motion_blur, "defocus": seq.defocus, "time": [float(v) for v in times],
            "camera": {"type": "thinlens" if intr.thin_lens else "perspective", "to_world": to_world.tolist(),
                       "x_fov": intr.x_fov, "aperture_radius": intr.aperture_radius,
                       "focus_distance": intr.focus_distance, "near_clip": intr.near_clip,
                       "far_clip": intr.far_clip},
            "seeds": {"passes": seeds, "reference": ref_seeds}, "max_depth": seq.max_depth,
            "source": seq.source,
        }
        return Frame(**px, motion=motion, valid=valid[..., None].astype(np.float32),
                     reference=reference, samples=samples, meta=meta)


def render_sequence(mi, seq: Sequence, folder: str, spp: int, ref_spp: int, variant: str,
                    progress: Callable[[int], None] | None = None,
                    on_frame: Callable[[int], None] | None = None, pixel_only: bool = False,
                    keep: Callable[[int], bool] | None = None) -> float:
    """Render and write every frame of ``seq`` into ``folder``; returns the seconds it took.
    ``progress(n)`` is called after every render call, ``on_frame(t)`` after every frame.
    ``pixel_only`` drops the per-sample layers from the files (pixel models, small samples).
    ``keep(t)`` true: frame t is already in ``folder`` from an interrupted render with the same
    settings and is not rendered again (every frame's seeds depend on the frame alone, so the
    kept file equals what rendering it again would write)."""
    os.makedirs(folder, exist_ok=True)
    start = _time.perf_counter()
    renderer = SequenceRenderer(mi, seq, spp, ref_spp, variant)
    if seq.source != "procedural":
        os.makedirs(os.path.join(folder, SCENE_DIR), exist_ok=True)
        cam.save_camera_path(os.path.join(folder, SCENE_DIR, "camera_path.json"),
                             seq.path.key_frames(seq.frames), seq.intrinsics)
    for t in range(seq.frames):
        if keep is not None and keep(t):
            if progress:
                progress(passes_per_frame(spp, ref_spp, seq.motion_blur))
            continue
        try:
            frame = renderer.render_frame(t, progress)
        except Exception as e:  # Mitsuba and the checks raise RuntimeError; name where it happened
            raise RenderError(f"{seq.name}: frame {t}: {one_line(e)}") from e
        if pixel_only:
            frame.samples = None
        write_frame(os.path.join(folder, frame_name(t)), frame)
        if on_frame:
            on_frame(t)
    return _time.perf_counter() - start
