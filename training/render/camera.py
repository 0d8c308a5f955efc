"""Camera model and camera paths in numpy, matching Mitsuba 3's ``perspective`` and ``thinlens``.

Conventions (Mitsuba's): a camera's ``to_world`` is a 4x4 matrix whose columns are the camera's
local +x (screen left), +y (screen up), +z (forward) and its position.  Pixel coordinates are
x right, y down, pixel centres at integer + 0.5, as in :mod:`runtime.frames`.

A camera path maps continuous time u (in frames: frame t is u = t, its shutter covers
[t, t + 1)) to a ``to_world`` matrix, so motion blur and motion vectors sample the same curve.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Sensor settings that do not move.

    width, height: film size in pixels.  x_fov: horizontal field of view in degrees.
    aperture_radius: thin-lens radius in scene units (0: pinhole).  focus_distance: camera-space
    depth of the focal plane in scene units (ignored for a pinhole).  near_clip, far_clip: scene units.
    """

    width: int
    height: int
    x_fov: float
    aperture_radius: float = 0.0
    focus_distance: float = 1.0
    near_clip: float = 0.01
    far_clip: float = 1e4

    @property
    def thin_lens(self) -> bool:
        return self.aperture_radius > 0.0

    def sensor_dict(self, to_world, spp: int = 1) -> dict:
        """Mitsuba sensor dict (``to_world`` passed through unchanged: matrix or transform).

        The film uses a box reconstruction filter: the default Gaussian spreads one sample over
        ~5x5 pixels, which would mix samples and break per-sample data.
        """
        d = {
            "type": "thinlens" if self.thin_lens else "perspective",
            "fov": float(self.x_fov), "fov_axis": "x",
            "near_clip": float(self.near_clip), "far_clip": float(self.far_clip),
            "to_world": to_world,
            "film": {"type": "hdrfilm", "width": int(self.width), "height": int(self.height),
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": int(spp)},
        }
        if self.thin_lens:
            d["aperture_radius"] = float(self.aperture_radius)
            d["focus_distance"] = float(self.focus_distance)
        return d

    def to_json(self) -> dict:
        return asdict(self)


def look_at(origin, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """``to_world`` (4, 4) float64 of a camera at ``origin`` looking at ``target``, as Mitsuba's
    ``Transform4f.look_at`` builds it (local +x = up x forward, i.e. screen left)."""
    origin = np.asarray(origin, np.float64)
    fwd = np.asarray(target, np.float64) - origin
    fwd /= np.linalg.norm(fwd)
    left = np.cross(np.asarray(up, np.float64), fwd)
    n = np.linalg.norm(left)
    if n < 1e-9:
        raise ValueError(f"look_at: up {tuple(up)} is parallel to the view direction")
    left /= n
    new_up = np.cross(fwd, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, fwd, origin
    return m


def to_camera(points: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """World points (..., 3) -> camera-space points (..., 3) (z = depth along the view axis)."""
    inv = np.linalg.inv(np.asarray(to_world, np.float64))
    return points @ inv[:3, :3].T + inv[:3, 3]


def project(points: np.ndarray, to_world: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (..., 3) through the lens centre.

    Returns (xy (..., 2) pixel coordinates, x right / y down / centres at +0.5; z (...,)
    camera-space depth, <= 0 behind the camera).  For a thin lens this is where the point
    would be in focus; its actual image is spread over the circle of confusion.
    """
    pc = to_camera(np.asarray(points, np.float64), to_world)
    z = pc[..., 2]
    safe = np.where(np.abs(z) > 1e-12, z, 1e-12)
    cot = 1.0 / math.tan(math.radians(intr.x_fov) / 2.0)
    aspect = intr.width / intr.height
    # Mitsuba's camera_to_sample: sample = (0.5 - 0.5 cot x/z, 0.5 - 0.5 aspect cot y/z)
    sx = 0.5 - 0.5 * cot * pc[..., 0] / safe
    sy = 0.5 - 0.5 * aspect * cot * pc[..., 1] / safe
    return np.stack([sx * intr.width, sy * intr.height], axis=-1), z


def coc_pixels(z: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """Thin-lens circle-of-confusion diameter in pixels for camera-space depths z (...,).

    A point at depth z spreads over a disc of diameter 2 A |z - F| / z on the focal plane
    (depth F), which is 2 F tan(fov/2) wide across the image.  0 for a pinhole or z <= 0.
    """
    z = np.asarray(z, np.float64)
    if not intr.thin_lens:
        return np.zeros_like(z)
    f = intr.focus_distance
    plane_width = 2.0 * f * math.tan(math.radians(intr.x_fov) / 2.0)
    safe = np.where(z > 0, z, 1.0)
    return np.where(z > 0, 2.0 * intr.aperture_radius * np.abs(z - f) / safe * intr.width / plane_width, 0.0)


# ----------------------------------------------------------------------------------------------
# Rotations (for interpolating key frames)
# ----------------------------------------------------------------------------------------------

def _quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a 3x3 rotation matrix."""
    t = np.trace(r)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[k, k], 1e-300))
        q = [0.0] * 4
        q[0] = (r[k, j] - r[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (r[j, i] + r[i, j]) / s
        q[1 + k] = (r[k, i] + r[i, k]) / s
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def _matrix_from_quat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    d = float(np.dot(q0, q1))
    if d < 0:  # take the short way round
        q1, d = -q1, -d
    if d > 0.9995:  # nearly equal: slerp's sin(theta) denominator loses precision
        q = q0 + a * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(min(d, 1.0))
    return (math.sin((1 - a) * theta) * q0 + math.sin(a * theta) * q1) / math.sin(theta)


def _split(m: np.ndarray):
    """4x4 affine -> (rotation 3x3, per-axis scale (3,), translation (3,))."""
    lin = m[:3, :3]
    scale = np.linalg.norm(lin, axis=0)
    rot = lin / scale
    if np.linalg.det(rot) < 0:  # a mirrored camera (negative x scale) keeps its mirror in the scale
        scale[0], rot[:, 0] = -scale[0], -rot[:, 0]
    return rot, scale, m[:3, 3]


def interpolate_pose(m0: np.ndarray, m1: np.ndarray, a: float) -> np.ndarray:
    """Pose a in [0, 1] of the way from ``m0`` to ``m1``: slerp rotation, lerp scale and position."""
    r0, s0, t0 = _split(np.asarray(m0, np.float64))
    r1, s1, t1 = _split(np.asarray(m1, np.float64))
    r = _matrix_from_quat(_slerp(_quat_from_matrix(r0), _quat_from_matrix(r1), a))
    out = np.eye(4)
    out[:3, :3] = r * ((1 - a) * s0 + a * s1)
    out[:3, 3] = (1 - a) * t0 + a * t1
    return out


def rotation(axis, degrees: float) -> np.ndarray:
    """4x4 rotation about ``axis`` (through the origin) by ``degrees``, right-handed."""
    axis = np.asarray(axis, np.float64)
    axis = axis / np.linalg.norm(axis)
    a = math.radians(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    m = np.eye(4)
    m[:3, :3] = np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * (k @ k)
    return m


def translation(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


# ----------------------------------------------------------------------------------------------
# Camera paths
# ----------------------------------------------------------------------------------------------

class CameraPath:
    """A camera pose for every continuous time u (frames); subclasses define :meth:`to_world`."""

    def to_world(self, u: float) -> np.ndarray:
        raise NotImplementedError(f"{type(self).__name__} must define to_world")

    def key_frames(self, frames: int) -> list[np.ndarray]:
        """``to_world`` at u = 0, 1, ..., frames - 1."""
        return [self.to_world(float(t)) for t in range(frames)]


@dataclass(frozen=True)
class FlyThrough(CameraPath):
    """Procedural fly-through: the camera orbits ``center`` while its distance and height
    drift and the look-at target slides, so frames show both rotation and translation.

    center: (3,) orbit centre; radius: initial distance; elevation: degrees above the
    horizontal; azimuth: degrees; omega: orbit speed in degrees per frame; radial, rise:
    distance / height change per frame (scene units); target: (3,) initial look-at point;
    drift: (3,) look-at velocity per frame; radius_range: (min, max) the distance is clamped to.
    """

    center: tuple
    radius: float
    elevation: float
    azimuth: float
    omega: float
    radial: float
    rise: float
    target: tuple
    drift: tuple
    radius_range: tuple

    def position(self, u: float) -> np.ndarray:
        r = float(np.clip(self.radius + self.radial * u, *self.radius_range))
        az = math.radians(self.azimuth + self.omega * u)
        el = math.radians(self.elevation)
        horiz = r * math.cos(el)
        c = np.asarray(self.center, np.float64)
        return c + np.array([horiz * math.sin(az), r * math.sin(el) + self.rise * u, horiz * math.cos(az)])

    def to_world(self, u: float) -> np.ndarray:
        target = np.asarray(self.target, np.float64) + u * np.asarray(self.drift, np.float64)
        return look_at(self.position(u), target)


@dataclass(frozen=True)
class Relative(CameraPath):
    """A path relative to a base pose: ``base @ translate(velocity u) @ rotate(axis, omega u)``
    in the camera's own frame (used around the sensor of a user's scene).

    base: 4x4 nested tuple; velocity: (3,) scene units per frame in camera space;
    axis: (3,) camera-space rotation axis; omega: degrees per frame.
    """

    base: tuple
    velocity: tuple
    axis: tuple
    omega: float

    def to_world(self, u: float) -> np.ndarray:
        base = np.asarray(self.base, np.float64)
        return base @ translation(np.asarray(self.velocity) * u) @ rotation(self.axis, self.omega * u)


class KeyFrames(CameraPath):
    """Per-frame ``to_world`` matrices (u = 0, 1, ...); poses in between are interpolated
    (slerp), and past either end the first/last step is repeated, so the last frame has a
    shutter interval and the first a predecessor."""

    def __init__(self, matrices):
        mats = [np.asarray(m, np.float64) for m in matrices]
        if not mats:
            raise ValueError("camera path has no frames")
        for i, m in enumerate(mats):
            if m.shape != (4, 4) or not np.all(np.isfinite(m)):
                raise ValueError(f"camera path frame {i}: to_world must be a finite 4x4 matrix, "
                                 f"got shape {m.shape}")
        self.matrices = mats

    def __len__(self) -> int:
        return len(self.matrices)

    def to_world(self, u: float) -> np.ndarray:
        mats, n = self.matrices, len(self.matrices)
        if n == 1:
            return mats[0].copy()
        if u < 0:
            return interpolate_pose(mats[0], _one_step_past(mats[1], mats[0]), min(-u, 1.0))
        i = int(math.floor(u))
        if i >= n - 1:
            return interpolate_pose(mats[n - 1], _one_step_past(mats[n - 2], mats[n - 1]), min(u - (n - 1), 1.0))
        return interpolate_pose(mats[i], mats[i + 1], u - i)


def _one_step_past(m0: np.ndarray, m1: np.ndarray) -> np.ndarray:
    """The pose after ``m1`` at constant velocity: position moves on by the same offset, the
    rotation turns by the same relative rotation, scale stays."""
    r0, _, t0 = _split(m0)
    r1, s1, t1 = _split(m1)
    out = np.eye(4)
    out[:3, :3] = (r1 @ r0.T @ r1) * s1
    out[:3, 3] = 2 * t1 - t0
    return out


def save_camera_path(path: str | os.PathLike, matrices, intr: Intrinsics | None = None) -> None:
    """Write per-frame ``to_world`` matrices (and the intrinsics) as JSON, the format
    ``--camera-path`` reads."""
    doc = {"frames": [{"to_world": np.asarray(m, np.float64).tolist()} for m in matrices]}
    if intr is not None:
        doc["intrinsics"] = intr.to_json()
    with open(path, "w") as fh:
        json.dump(doc, fh, indent=1)


def load_camera_path(path: str | os.PathLike) -> tuple[KeyFrames, dict]:
    """Read a camera path JSON: ``{"frames": [{"to_world": 4x4}, ...], "intrinsics": {...}}``
    or a bare list of 4x4 matrices.  Returns (KeyFrames, intrinsics dict, possibly empty)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: camera path file not found")
    try:
        with open(path) as fh:
            doc = json.load(fh)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a readable JSON file ({e})") from None
    if isinstance(doc, list):
        frames, intr = doc, {}
    elif isinstance(doc, dict) and isinstance(doc.get("frames"), list):
        frames, intr = doc["frames"], doc.get("intrinsics") or {}
    else:
        raise ValueError(f'{path}: expected a list of 4x4 matrices or {{"frames": [{{"to_world": ...}}]}}')
    try:
        mats = [np.asarray(f["to_world"] if isinstance(f, dict) else f, np.float64) for f in frames]
        return KeyFrames(mats), dict(intr)
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: {e}") from None
