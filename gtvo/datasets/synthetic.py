"""A deterministic synthetic stereo sequence with exact depth and poses (the demo's default data).

The scene is a closed room (an axis-aligned box seen from inside) holding a few axis-aligned boxes.
Every face carries its own procedural texture: smooth value noise summed over octaves plus
soft-edged blobs, band-limited so that the rendered images are well sampled and follow the
bilinear interpolation model that direct methods assume. Rendering is exact ray casting: each
pixel's ray (pixel centres at integer ``(u, v)``, docs/conventions.md) is intersected with the
room and the boxes analytically, the nearest hit gives the exact depth ``z`` and the texture value
at the hit's 2-D face coordinates. Everything is vectorised over the pixels.

Public API:

* :func:`make_synthetic_sequence` -> :class:`SyntheticSequence` (a :class:`gtvo.datasets.sequence.Sequence`
  of kind ``"stereo"`` with ground truth, rendered lazily and LRU-cached), whose extra accessors
  are :meth:`SyntheticSequence.true_depth` (exact depth maps), :attr:`SyntheticSequence.affine_left`
  / :attr:`SyntheticSequence.affine_right` (the known brightness change) and
  :attr:`SyntheticSequence.scene` (to render any other view).
* :func:`synthetic_trajectory`, :func:`make_scene`, :class:`SyntheticScene` (``render``).
* :func:`write_sequence_kitti`: any stereo sequence to the KITTI odometry layout.

The maths and the measured limits of exactness: docs/synthetic.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from gtvo.io.atomic import atomic_dir
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError
from gtvo.datasets.sequence import Sequence

FloatArray = NDArray[np.float64]
Motion = Literal["forward", "loop", "turn"]

#: Frame rate of the generated sequences (Hz), KITTI's.
FRAME_RATE_HZ = 10.0
#: Default stereo baseline (m).
DEFAULT_BASELINE = 0.5
#: Texel size of the face textures (m).
TEXEL_M = 0.01
#: Lattice spacings (m) of the value-noise octaves and their amplitudes (gray levels, before squashing).
NOISE_OCTAVES: tuple[tuple[float, float], ...] = ((2.56, 26.0), (1.28, 26.0), (0.64, 28.0), (0.32, 24.0))
#: Lattice spacing (m) of the field whose threshold gives the soft-edged blobs, their contrast (gray)
#: and the Gaussian width (m) of their edges.
BLOB_LATTICE_M = 0.48
BLOB_CONTRAST = 50.0
BLOB_EDGE_SIGMA_M = 0.07
#: Faces along the direction of travel (texture rows along world z) are seen foreshortened; their
#: texture is stretched along z by this factor, per face axis (x-walls, floor/ceiling), against aliasing.
Z_STRETCH: dict[int, float] = {0: 2.0, 1: 3.0, 2: 1.0}
#: The texture is squashed smoothly into ``MEAN +- HALF_RANGE`` (gray): headroom for exposure changes.
TEXTURE_MEAN = 118.0
TEXTURE_HALF_RANGE = 82.0
#: The ``"turn"`` motion: straight for this many frames, then a constant yaw rate (deg per frame,
#: to the right; 30 deg/s at 10 Hz, a car's tight urban turn).
TURN_START_FRAME = 8
TURN_DEG_PER_FRAME = 3.0
#: Camera height above the ground (m) and the room's height (m); the world y axis points down.
CAMERA_HEIGHT_M = 1.4
ROOM_HEIGHT_M = 3.4


# --------------------------------------------------------------------------------------------- scene


class Rendering(NamedTuple):
    """One rendered view, all (H, W): float32 intensity (gray), float32 depth z (m), int16 face index."""

    intensity: NDArray[np.float32]
    depth: NDArray[np.float32]
    face: NDArray[np.int16]


@dataclass(frozen=True)
class _Face:
    """An axis-aligned rectangle: ``x[axis] = value``; texture coordinates along ``s_axis``, ``t_axis``."""

    axis: int
    value: float
    s_axis: int
    t_axis: int
    lo: tuple[float, float]  # (s, t) of the texture origin (m)
    size: tuple[int, int]  # texture (rows along t, cols along s) in texels


class SyntheticScene:
    """A textured room with boxes inside, rendered exactly by ray casting.

    Args:
        room_lo, room_hi: opposite corners of the room (world frame, metres); cameras must be inside.
        boxes: list of ``(lo, hi)`` corners of axis-aligned boxes inside the room.
        seed: seed of the textures (each face draws from its own stream, so adding a box does not
            change the other faces).
    """

    def __init__(self, room_lo: ArrayLike, room_hi: ArrayLike, boxes: list[tuple[ArrayLike, ArrayLike]],
                 seed: int = 0) -> None:
        self.room_lo = np.asarray(room_lo, dtype=np.float64).reshape(3)
        self.room_hi = np.asarray(room_hi, dtype=np.float64).reshape(3)
        if not np.all(self.room_hi > self.room_lo):
            raise InputError(f"room corners must satisfy lo < hi, got {self.room_lo} and {self.room_hi}")
        self.boxes = [(np.asarray(lo, float).reshape(3), np.asarray(hi, float).reshape(3)) for lo, hi in boxes]
        for lo, hi in self.boxes:
            if not (np.all(hi > lo) and np.all(lo > self.room_lo - 1e-9) and np.all(hi < self.room_hi + 1e-9)):
                raise InputError(f"box {lo}..{hi} is empty or outside the room")
        self.seed = int(seed)
        # Faces: room faces 0..5, then 6 per box; face 2k + side is x[k] = lo (side 0) or hi (side 1).
        self.faces: list[_Face] = []
        for lo, hi in [(self.room_lo, self.room_hi)] + self.boxes:
            for k in range(3):
                s_axis, t_axis = [a for a in range(3) if a != k]
                size = (int(np.ceil((hi[t_axis] - lo[t_axis]) / TEXEL_M)) + 2,
                        int(np.ceil((hi[s_axis] - lo[s_axis]) / TEXEL_M)) + 2)
                for value in (lo[k], hi[k]):
                    self.faces.append(_Face(k, float(value), s_axis, t_axis, (float(lo[s_axis]), float(lo[t_axis])),
                                            size))
        textures = [face_texture(f.size, self.seed, i, Z_STRETCH[f.axis] if f.t_axis == 2 else 1.0)
                    for i, f in enumerate(self.faces)]
        self._atlas = np.concatenate([t.ravel() for t in textures]).astype(np.float32)
        sizes = np.array([t.size for t in textures])
        self._offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.intp)
        self._stride = np.array([f.size[1] for f in self.faces], dtype=np.intp)
        self._max_col = np.array([f.size[1] - 1 for f in self.faces], dtype=np.float64)
        self._max_row = np.array([f.size[0] - 1 for f in self.faces], dtype=np.float64)
        self._max_col_i = self._max_col.astype(np.intp)
        self._max_row_i = self._max_row.astype(np.intp)
        self._axis = np.array([f.axis for f in self.faces], dtype=np.intp)
        self._s0 = np.array([f.lo[0] for f in self.faces])
        self._t0 = np.array([f.lo[1] for f in self.faces])

    def contains(self, point: ArrayLike) -> bool:
        """True when ``point`` lies inside the room and outside every box (a valid camera centre)."""
        p = np.asarray(point, dtype=float).reshape(3)
        if not (np.all(p > self.room_lo) and np.all(p < self.room_hi)):
            return False
        return not any(np.all(p >= lo) and np.all(p <= hi) for lo, hi in self.boxes)

    def raycast(self, origin: ArrayLike, directions: ArrayLike) -> tuple[FloatArray, NDArray[np.intp]]:
        """Nearest hit of rays ``origin + t * directions`` (N, 3): returns ``(t, face index)``.

        ``origin`` must be inside the room and outside the boxes, so every ray hits a face (the room
        is closed). ``t`` is in units of the direction's length (camera rays with unit z give depth).
        """
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        t, face = self._raycast_xyz(np.asarray(origin, dtype=np.float64).reshape(3), (d[:, 0], d[:, 1], d[:, 2]))
        return t, face

    def _raycast_xyz(self, o: FloatArray, d: tuple[FloatArray, FloatArray, FloatArray]
                     ) -> tuple[FloatArray, NDArray[np.intp]]:
        """:meth:`raycast` on direction components ``(dx, dy, dz)`` of any equal shapes (fast path)."""
        d = tuple(np.where(np.abs(dk) < 1e-12, 1e-12, dk) for dk in d)  # no exact zeros: slabs stay finite
        inv = tuple(1.0 / dk for dk in d)
        positive = tuple(dk > 0 for dk in d)
        # Room (seen from inside): the ray leaves through the nearest of the three faces ahead.
        t_axis = [(np.where(positive[k], self.room_hi[k], self.room_lo[k]) - o[k]) * inv[k] for k in range(3)]
        t = np.minimum(np.minimum(t_axis[0], t_axis[1]), t_axis[2])
        face = np.where(t_axis[0] == t, positive[0],
                        np.where(t_axis[1] == t, 2 + positive[1], 4 + positive[2])).astype(np.intp)
        # Boxes (seen from outside): slab test; the entry face belongs to the last slab entered.
        for b, (lo, hi) in enumerate(self.boxes):
            t_in = []
            t_far = t
            for k in range(3):
                t1 = (lo[k] - o[k]) * inv[k]
                t2 = (hi[k] - o[k]) * inv[k]
                t_in.append(np.minimum(t1, t2))
                t_far = np.minimum(t_far, np.maximum(t1, t2))
            t_near = np.maximum(np.maximum(t_in[0], t_in[1]), t_in[2])
            hit = (t_near <= t_far) & (t_near > 0) & (t_near < t)
            if np.any(hit):
                tn = t_near[hit]
                k_hit = np.where(t_in[0][hit] == tn, 0, np.where(t_in[1][hit] == tn, 1, 2))
                moving_pos = np.where(k_hit == 0, positive[0][hit], np.where(k_hit == 1, positive[1][hit],
                                                                             positive[2][hit]))
                t[hit] = tn
                face[hit] = 6 + 6 * b + 2 * k_hit + ~moving_pos  # enter x[k] = lo when moving +
        return t, face

    def shade(self, points: ArrayLike, face: NDArray[np.intp]) -> NDArray[np.float32]:
        """Texture intensity (gray levels) at world points (N, 3) lying on faces ``face`` (N,).

        The texture of a face is the bilinear interpolation of its texel array (texel centres every
        ``TEXEL_M`` metres from the face's corner), so this is exact, not an approximation.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self._shade_xyz((p[:, 0], p[:, 1], p[:, 2]), np.asarray(face, dtype=np.intp).reshape(-1))

    def _shade_xyz(self, p: tuple[FloatArray, FloatArray, FloatArray], face: NDArray[np.intp]
                   ) -> NDArray[np.float32]:
        axis = self._axis[face]
        s = np.where(axis == 0, p[1], p[0])  # face _|_ x: (s, t) = (y, z); _|_ y: (x, z); _|_ z: (x, y)
        tt = np.where(axis == 2, p[1], p[2])
        col = np.clip((s - self._s0[face]) * (1.0 / TEXEL_M), 0.0, self._max_col[face])
        row = np.clip((tt - self._t0[face]) * (1.0 / TEXEL_M), 0.0, self._max_row[face])
        c0 = np.minimum(col.astype(np.intp), self._max_col_i[face] - 1)
        r0 = np.minimum(row.astype(np.intp), self._max_row_i[face] - 1)
        ac = (col - c0).astype(np.float32)
        ar = (row - r0).astype(np.float32)
        stride = self._stride[face]
        i00 = self._offset[face] + r0 * stride + c0
        a = self._atlas
        top = a[i00] + ac * (a[i00 + 1] - a[i00])
        i10 = i00 + stride
        bottom = a[i10] + ac * (a[i10 + 1] - a[i10])
        return top + ar * (bottom - top)

    def render(self, T_world_cam: ArrayLike, camera: PinholeCamera, supersample: int = 1) -> "Rendering":
        """Render the view of ``camera`` at ``T_world_cam``: intensity, exact depth and face index, (H, W).

        ``depth`` is the exact z (m) of the surface hit by the ray through each pixel centre and
        ``face`` that surface's index. ``intensity`` is the texture at that hit (``supersample=1``,
        the exact model), or the mean of an ``supersample x supersample`` grid of rays spread
        evenly over the pixel (box-filter anti-aliasing of creases and silhouettes, at the cost of
        a slight view-dependent blur).
        """
        if int(supersample) < 1:
            raise InputError(f"supersample must be >= 1, got {supersample}")
        s = int(supersample)
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"T_world_cam must be a finite 4x4 matrix, got shape {T.shape}")
        R, o = T[:3, :3], T[:3, 3]
        if not self.contains(o):
            raise InputError(f"camera centre {o} is outside the room or inside a box")
        h, w = camera.height, camera.width
        depth, face, dirs = self._cast_grid(R, o, camera, h, w, np.zeros(1))
        if s == 1:
            intensity = self._shade_xyz(tuple(o[k] + dirs[k] * depth for k in range(3)), face)
        else:
            t_s, face_s, dirs_s = self._cast_grid(R, o, camera, h, w, (np.arange(s) + 0.5) / s - 0.5)
            samples = self._shade_xyz(tuple(o[k] + dirs_s[k] * t_s for k in range(3)), face_s)
            intensity = samples.reshape(h, s, w, s).mean(axis=(1, 3), dtype=np.float64)
        return Rendering(intensity.reshape(h, w).astype(np.float32), depth.reshape(h, w).astype(np.float32),
                         face.reshape(h, w).astype(np.int16))

    def _cast_grid(self, R: FloatArray, o: FloatArray, camera: PinholeCamera, h: int, w: int,
                   offsets: FloatArray) -> tuple[FloatArray, NDArray[np.intp], tuple[FloatArray, ...]]:
        """Cast the rays of a (h*s, w*s) grid of sub-pixel positions ``pixel + offsets`` (s = len(offsets)).

        Returns flat arrays in row-major order of that grid (rows: v then sub-v; columns: u then sub-u).
        """
        u = (np.arange(w)[:, None] + offsets[None, :]).reshape(1, -1)
        v = (np.arange(h)[:, None] + offsets[None, :]).reshape(-1, 1)
        x = (u - camera.cx) / camera.fx  # camera ray (x, y, 1): unit z, so t is the depth
        y = (v - camera.cy) / camera.fy
        dirs = tuple((R[k, 0] * x + R[k, 1] * y + R[k, 2]).reshape(-1) for k in range(3))
        t, face = self._raycast_xyz(o, dirs)
        return t, face, dirs


def _upsampled_noise(rng: np.random.Generator, size: tuple[int, int], lattice_m: float,
                     row_stretch: float = 1.0) -> NDArray[np.float32]:
    """Value noise: a unit-variance random lattice every ``lattice_m`` metres (times ``row_stretch``
    along the rows), bicubically interpolated to the texel grid."""
    fc = int(round(lattice_m / TEXEL_M))
    fr = int(round(lattice_m * row_stretch / TEXEL_M))
    rows = size[0] // fr + 4
    cols = size[1] // fc + 4
    lattice = rng.standard_normal((rows, cols)).astype(np.float32)
    up = cv2.resize(lattice, (cols * fc, rows * fr), interpolation=cv2.INTER_CUBIC)
    r0 = int(rng.integers(0, fr))
    c0 = int(rng.integers(0, fc))
    return up[r0 + fr:r0 + fr + size[0], c0 + fc:c0 + fc + size[1]]


def face_texture(size: tuple[int, int], seed: int, face_index: int, row_stretch: float = 1.0) -> NDArray[np.float32]:
    """The texel array (rows, cols) of one face: octave noise + soft blobs, squashed into the gray range.

    Deterministic in ``(seed, face_index)``. Intensity = ``MEAN + HALF_RANGE * tanh(x / HALF_RANGE)``
    with ``x = face offset + sum_k A_k n_k + BLOB_CONTRAST * (blob - 1/2)``: smooth (C1) everywhere,
    band-limited by the finest lattice (``NOISE_OCTAVES``) and the blob edge width.
    """
    rng = np.random.default_rng([int(seed), int(face_index), 0x5EED])
    x = np.full(size, rng.uniform(-20.0, 20.0), dtype=np.float32)
    for lattice_m, amplitude in NOISE_OCTAVES:
        x += amplitude * _upsampled_noise(rng, size, lattice_m, row_stretch)
    blob_field = _upsampled_noise(rng, size, BLOB_LATTICE_M, row_stretch)
    blob = (blob_field > 0.35).astype(np.float32)
    sigma = BLOB_EDGE_SIGMA_M / TEXEL_M
    blob = cv2.GaussianBlur(blob, (0, 0), sigmaX=sigma, sigmaY=sigma * row_stretch, borderType=cv2.BORDER_REFLECT)
    x += BLOB_CONTRAST * (blob - 0.5)
    return (TEXTURE_MEAN + TEXTURE_HALF_RANGE * np.tanh(x / TEXTURE_HALF_RANGE)).astype(np.float32)


@functools.lru_cache(maxsize=4)
def _cached_scene(room_lo: tuple[float, ...], room_hi: tuple[float, ...],
                  boxes: tuple[tuple[tuple[float, ...], tuple[float, ...]], ...], seed: int) -> SyntheticScene:
    return SyntheticScene(room_lo, room_hi, [(lo, hi) for lo, hi in boxes], seed)


def make_scene(positions: ArrayLike, seed: int = 0) -> SyntheticScene:
    """The room and boxes around a camera path ``positions`` (N, 3), world frame (y down).

    The room spans the path with 3.5 m to each side, 3 m behind and 10 m ahead (z), the ground
    ``CAMERA_HEIGHT_M`` below the path and the ceiling ``ROOM_HEIGHT_M`` above the ground. Boxes
    stand on the ground every 4.5 m from 5.5 m ahead of the start, alternating sides, 0.9-1.4 m clear of the path.
    Scenes are cached (the same path and seed give the same object).
    """
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(p)):
        raise InputError("camera path contains NaN or infinite positions")
    lo_p, hi_p = p.min(axis=0), p.max(axis=0)
    ground = round(float(hi_p[1]) + CAMERA_HEIGHT_M, 6)
    room_lo = (round(float(lo_p[0]) - 3.5, 6), round(ground - ROOM_HEIGHT_M, 6), round(float(lo_p[2]) - 3.0, 6))
    room_hi = (round(float(hi_p[0]) + 3.5, 6), ground, round(float(hi_p[2]) + 10.0, 6))
    rng = np.random.default_rng([int(seed), 0xB0C5])
    boxes = []
    z = max(float(lo_p[2]), 0.0) + 5.5
    side = 1
    while z < room_hi[2] - 2.5:
        width, length, height = rng.uniform(0.7, 1.1), rng.uniform(0.7, 1.2), rng.uniform(0.7, 1.6)
        gap = rng.uniform(0.9, 1.4)
        if side > 0:
            x_lo = float(hi_p[0]) + gap
        else:
            x_lo = float(lo_p[0]) - gap - width
        zc = z + rng.uniform(-0.5, 0.5)
        lo = (round(x_lo, 6), round(ground - height, 6), round(zc - length / 2, 6))
        hi = (round(x_lo + width, 6), ground, round(zc + length / 2, 6))
        boxes.append((lo, hi))
        z += 4.5
        side = -side
    return _cached_scene(room_lo, room_hi, tuple(boxes), int(seed))


# -------------------------------------------------------------------------------------------- motion


def _rotation_ypr(yaw: float, pitch: float, roll: float) -> FloatArray:
    """``R = Ry(yaw) Rx(pitch) Rz(roll)`` (camera axes: y down, so yaw turns about the vertical)."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def synthetic_trajectory(n_frames: int, motion: Motion = "forward", step_m: float = 0.15,
                         frame_rate_hz: float = FRAME_RATE_HZ) -> NDArray[np.float64]:
    """Ground-truth ``T_world_cam`` (N, 4, 4) of the left camera; frame 0 is the identity.

    ``"forward"``: ``z = v t`` (``v = step_m * frame_rate``) with a lateral sway of 0.25 m, a 4 cm
    vertical bob and yaw / pitch / roll wobbles of 4 / 1.5 / 1 degrees (peak rates about 4, 2.5 and
    1.5 deg/s). ``"loop"``: an ellipse in the x-z plane (semi-axes ``A_z`` forward, ``A_z/2``
    sideways, perimeter ``n_frames * step_m``) run once over the sequence with periodic wobbles, so
    frame ``n_frames`` would coincide with frame 0: the last frame is one step before the start.
    ``"turn"``: a car's turn, heading along the path: straight for :data:`TURN_START_FRAME` frames,
    then yawing right by :data:`TURN_DEG_PER_FRAME` per frame (an arc of radius
    ``step_m / TURN_DEG_PER_FRAME`` in radians), no wobbles; past about 80 deg the camera faces the
    room's side wall, close and with little texture at that range (a conditioning test).
    """
    n = int(n_frames)
    if n < 1:
        raise InputError(f"n_frames must be >= 1, got {n_frames}")
    if not (np.isfinite(step_m) and step_m > 0):
        raise InputError(f"step_m must be a finite positive number, got {step_m!r}")
    dt = 1.0 / float(frame_rate_hz)
    t = np.arange(n) * dt
    deg = np.pi / 180.0
    if motion == "forward":
        v = step_m / dt
        pos = np.stack([0.25 * np.sin(2 * np.pi * t / 5.0), 0.04 * np.sin(2 * np.pi * t / 2.9), v * t], axis=1)
        yaw = 4.0 * deg * np.sin(2 * np.pi * t / 6.0)
        pitch = 1.5 * deg * np.sin(2 * np.pi * t / 3.7)
        roll = 1.0 * deg * np.sin(2 * np.pi * t / 4.3)
    elif motion == "loop":
        period = n * dt
        s = 2 * np.pi * np.arange(n) / n
        a, b = 1.0, 0.5  # unit ellipse, scaled to the wanted perimeter (Ramanujan's formula)
        perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
        a_z = n * step_m / perimeter
        k = max(1, int(round(period / 6.0)))  # wobble cycles per loop: about 1/6 Hz
        rate_cap = 5.0 * deg / (2 * np.pi * k / period)  # keep peak rates <= ~5 deg/s
        pos = np.stack([0.5 * a_z * (1 - np.cos(s)), 0.04 * np.sin(2 * k * s), a_z * np.sin(s)], axis=1)
        yaw = min(4.0 * deg, rate_cap) * np.sin(k * s)
        pitch = min(1.5 * deg, rate_cap) * np.sin(2 * k * s) / 2
        roll = min(1.0 * deg, rate_cap) * np.sin(k * s + np.sin(s))
    elif motion == "turn":
        yaw = TURN_DEG_PER_FRAME * deg * np.maximum(np.arange(n) - TURN_START_FRAME, 0)
        heading = np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], axis=1)
        pos = np.concatenate([np.zeros((1, 3)), np.cumsum(step_m * heading[1:], axis=0)])
        pitch = roll = np.zeros(n)
    else:
        raise InputError(f"motion must be 'forward', 'loop' or 'turn', got {motion!r}")
    T = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        T[i, :3, :3] = _rotation_ypr(yaw[i], pitch[i], roll[i])
    T[:, :3, 3] = pos
    return T


def synthetic_exposures(n_frames: int, exposure_change: bool,
                        frame_rate_hz: float = FRAME_RATE_HZ) -> tuple[FloatArray, FloatArray]:
    """Per-frame affine brightness ``(a, b)`` of the left and right images, each (N, 2).

    An observed image is ``I = exp(a) * R + b`` with ``R`` the exposure-free render, so between
    images ``I_j = exp(a_j - a_i) * (I_i - b_i) + b_j``. Without ``exposure_change`` all are zero.
    With it, ``a`` swings by +-0.12 and ``b`` by +-6 gray over a few seconds (frame 0 has (0, 0)),
    and the right image has a constant extra ``(+0.04, -2.0)``.
    """
    n = int(n_frames)
    left = np.zeros((n, 2))
    right = np.zeros((n, 2))
    if exposure_change:
        t = np.arange(n) / float(frame_rate_hz)
        left[:, 0] = 0.08 * np.sin(2 * np.pi * t / 2.3) + 0.04 * np.sin(2 * np.pi * t / 0.9)
        left[:, 1] = 6.0 * np.sin(2 * np.pi * t / 3.1)
        right[:] = left + np.array([0.04, -2.0])
    return left, right


# ------------------------------------------------------------------------------------------ sequence


class _FrameRenderer:
    """Renders (and LRU-caches) frame ``i``: one :class:`Rendering` per side, exposure and noise applied."""

    def __init__(self, scene: SyntheticScene, camera: StereoCamera, poses: FloatArray, affine_left: FloatArray,
                 affine_right: FloatArray, noise_sigma: float, seed: int, supersample: int, cache_size: int):
        self.scene = scene
        self.camera = camera
        self.poses = poses
        self.affine = (affine_left, affine_right)
        self.noise_sigma = float(noise_sigma)
        self.seed = int(seed)
        self.supersample = int(supersample)
        self.render_frame = functools.lru_cache(maxsize=cache_size)(self._render_frame)

    def _render_frame(self, i: int) -> tuple[Rendering, Rendering]:
        T_left = self.poses[i]
        T_right = T_left @ np.linalg.inv(self.camera.T_right_left)
        out = []
        for side, T in enumerate((T_left, T_right)):
            radiance, depth, face = self.scene.render(T, self.camera.left, self.supersample)
            a, b = self.affine[side][i]
            img = np.exp(a) * radiance.astype(np.float64) + b
            if self.noise_sigma > 0:
                rng = np.random.default_rng([self.seed, int(i), side, 0x4015E])
                img = img + rng.normal(0.0, self.noise_sigma, img.shape)
            out.append(Rendering(np.clip(img, 0.0, 255.0).astype(np.float32), depth, face))
        return out[0], out[1]

    def get(self, i: int, side: int) -> Rendering:
        i = int(i)
        if not 0 <= i < self.poses.shape[0]:
            raise IndexError(f"frame {i} out of range 0..{self.poses.shape[0] - 1}")
        return self.render_frame(i)[side]

    def left(self, i: int) -> NDArray[np.float32]:
        return self.get(i, 0).intensity.copy()

    def right(self, i: int) -> NDArray[np.float32]:
        return self.get(i, 1).intensity.copy()


_SIDES = {"left": 0, "right": 1}


@dataclass
class SyntheticSequence(Sequence):
    """A generated stereo :class:`Sequence` that also knows its exact depth and brightness changes.

    Attributes (beyond :class:`Sequence`):
        scene: the :class:`SyntheticScene` (render any other view with ``scene.render``).
        affine_left, affine_right: (N, 2) known ``(a, b)`` per frame: ``I = exp(a) * R + b``.
        noise_sigma: standard deviation (gray) of the i.i.d. Gaussian noise added to every image.

    Exact depth is :meth:`true_depth` (not ``load_depth``, which marks RGB-D sequences), the
    surface seen by each pixel :meth:`face_ids`, and pixels away from creases and silhouettes
    :meth:`interior_mask`.
    """

    scene: SyntheticScene | None = None
    affine_left: FloatArray | None = None
    affine_right: FloatArray | None = None
    noise_sigma: float = 0.0
    _renderer: _FrameRenderer | None = field(default=None, repr=False)
    #: the renderer's frame of each of this sequence's frames (None: the same index), so that
    #: ``truncated`` / ``subsampled`` sub-sequences keep the exact depth and faces of their frames
    _frames: tuple[int, ...] | None = field(default=None, repr=False)

    def _rendering(self, i: int, side: str) -> Rendering:
        if side not in _SIDES:
            raise InputError(f"side must be 'left' or 'right', got {side!r}")
        if self._renderer is None:
            raise InputError(f"sequence {self.name} has no renderer; build it with make_synthetic_sequence")
        if self._frames is not None:
            if not 0 <= int(i) < len(self._frames):
                raise IndexError(f"frame {i} out of range 0..{len(self._frames) - 1}")
            i = self._frames[int(i)]
        return self._renderer.get(i, _SIDES[side])

    def true_depth(self, i: int, side: Literal["left", "right"] = "left") -> NDArray[np.float32]:
        """Exact depth z (m) of frame ``i`` along each pixel-centre ray, (H, W) float32, all > 0."""
        return self._rendering(i, side).depth.copy()

    def face_ids(self, i: int, side: Literal["left", "right"] = "left") -> NDArray[np.int16]:
        """Index of the scene face seen through each pixel centre of frame ``i``, (H, W) int16."""
        return self._rendering(i, side).face.copy()

    def interior_mask(self, i: int, side: Literal["left", "right"] = "left", margin: int = 2) -> NDArray[np.bool_]:
        """True where every pixel within ``margin`` (Chebyshev distance) sees the same face and lies
        at least ``margin`` pixels inside the image: away from creases, silhouettes and borders,
        where the image is smooth and the bilinear model holds (docs/synthetic.md)."""
        face = self._rendering(i, side).face
        m = int(margin)
        if m < 0:
            raise InputError(f"margin must be >= 0, got {margin}")
        size = 2 * m + 1
        same = ndimage.minimum_filter(face, size=size, mode="nearest") == ndimage.maximum_filter(
            face, size=size, mode="nearest")
        if m > 0:
            same[:m] = same[-m:] = False
            same[:, :m] = same[:, -m:] = False
        return same

    def _select(self, idx: list[int]) -> "SyntheticSequence":
        """:meth:`Sequence._select`, with the affines and the renderer's frame map sliced too, so that
        :meth:`truncated` and :meth:`subsampled` keep the exact depth of their frames."""
        base = self._frames if self._frames is not None else range(len(self))
        assert self.affine_left is not None and self.affine_right is not None
        return replace(super()._select(idx), affine_left=self.affine_left[idx],
                       affine_right=self.affine_right[idx], _frames=tuple(int(base[i]) for i in idx))


#: Largest synthetic image side (px): the renderer holds several float images per frame.
MAX_SIDE = 4096
#: Smallest synthetic image side (px).
MIN_SIDE = 16


def synthetic_camera(width: int = 320, height: int = 240, baseline: float = DEFAULT_BASELINE) -> StereoCamera:
    """The rectified stereo camera of the synthetic sequences: ``fx = fy = 0.9 * width``, centred."""
    if not (MIN_SIDE <= int(width) <= MAX_SIDE and MIN_SIDE <= int(height) <= MAX_SIDE):
        raise InputError(f"image size must be between {MIN_SIDE}x{MIN_SIDE} and {MAX_SIDE}x{MAX_SIDE}, "
                         f"got {width}x{height}")
    f = 0.9 * int(width)
    return StereoCamera(PinholeCamera(f, f, (int(width) - 1) / 2.0, (int(height) - 1) / 2.0, int(width), int(height)),
                        float(baseline))


def make_synthetic_sequence(n_frames: int = 30, width: int = 320, height: int = 240,
                            baseline: float = DEFAULT_BASELINE, step_m: float = 0.15, noise_sigma: float = 0.0,
                            exposure_change: bool = False, seed: int = 0, motion: Motion = "forward",
                            supersample: int = 1, cache_size: int = 32) -> SyntheticSequence:
    """A deterministic synthetic stereo sequence with exact poses and depth, rendered on demand.

    Args:
        n_frames: number of stereo pairs (10 Hz, timestamps ``i / 10`` s).
        width, height: image size; ``fx = fy = 0.9 * width``, principal point at the centre.
        baseline: stereo baseline (m); the right camera sits at ``+baseline`` along x.
        step_m: mean camera travel per frame (m).
        noise_sigma: i.i.d. Gaussian image noise (gray levels), deterministic per (seed, frame, side).
        exposure_change: apply the known per-frame affine brightness of :func:`synthetic_exposures`.
        seed: seeds textures, box layout and noise; the same arguments give byte-identical images.
        motion: ``"forward"``, ``"loop"`` or ``"turn"`` (see :func:`synthetic_trajectory`).
        supersample: rays per pixel side (1 = point sampling, the exact model; see docs/synthetic.md).
        cache_size: rendered frames kept (LRU; about 1.5 MB each at 320x240).
    """
    for name, value in (("noise_sigma", noise_sigma), ("baseline", baseline)):
        if not np.isfinite(value) or value < 0 or (name == "baseline" and value == 0):
            raise InputError(f"{name} must be finite and {'positive' if name == 'baseline' else '>= 0'}, "
                             f"got {value!r}")
    if int(supersample) < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")
    camera = synthetic_camera(width, height, baseline)
    poses = synthetic_trajectory(n_frames, motion, step_m)
    right_centres = poses[:, :3, 3] + poses[:, :3, 0] * baseline
    scene = make_scene(np.concatenate([poses[:, :3, 3], right_centres]), seed)
    affine_left, affine_right = synthetic_exposures(n_frames, exposure_change)
    renderer = _FrameRenderer(scene, camera, poses, affine_left, affine_right, noise_sigma, seed, supersample,
                              max(1, int(cache_size)))
    n = poses.shape[0]
    name = f"synthetic-{motion}-seed{int(seed)}"
    return SyntheticSequence(name, "stereo", camera, np.arange(n) / FRAME_RATE_HZ, renderer.left, renderer.right,
                             None, poses, None, [], scene=scene, affine_left=affine_left,
                             affine_right=affine_right, noise_sigma=float(noise_sigma), _renderer=renderer)


# -------------------------------------------------------------------------------------------- writer


def _matrix_line(M: ArrayLike) -> str:
    return " ".join(f"{x:.12e}" for x in np.asarray(M, dtype=np.float64).reshape(-1))


def write_sequence_kitti(seq: Sequence, folder: str | Path, progress: bool = False) -> Path:
    """Write a stereo sequence in the KITTI odometry layout, the folder as a whole.

    The files are written into a new folder that replaces ``folder`` when complete
    (:func:`gtvo.io.atomic.atomic_dir`): an interrupted write leaves the old folder intact, and a
    shorter sequence leaves none of a longer one's frames behind. An existing ``folder`` is
    replaced only when it is empty or was written here (it carries ``gtvo.io.atomic.DIR_MARKER``)
    and holds nothing else; a real dataset folder or one with other files is refused
    (:class:`InputError`), never overwritten.

    ``calib.txt`` (``P0:``/``P1:`` 3x4 rows, ``P1[0,3] = -fx * baseline``), ``image_0/`` and
    ``image_1/`` (8-bit PNG, ``NNNNNN.png``, intensities rounded and clipped to 0..255),
    ``times.txt`` and, when every frame has ground truth, ``poses.txt`` (3x4 row-major
    ``T_world_cam`` of the left camera).
    """
    if seq.kind != "stereo" or not isinstance(seq.camera, StereoCamera):
        raise InputError(f"sequence {seq.name} is not stereo; the KITTI layout needs a stereo pair")
    with atomic_dir(folder, KITTI_LAYOUT_ENTRIES, "gtvo synthetic") as tmp:
        _write_kitti_files(seq, tmp, Path(folder), progress)
    return Path(folder)


#: What :func:`write_sequence_kitti` writes into its folder (and may therefore replace there).
KITTI_LAYOUT_ENTRIES = frozenset({"calib.txt", "times.txt", "poses.txt", "image_0", "image_1"})


def _write_kitti_files(seq: Sequence, out: Path, shown: Path, progress: bool) -> None:
    """The files of :func:`write_sequence_kitti` into ``out``, a fresh temporary folder that
    :func:`gtvo.io.atomic.atomic_dir` swaps in as a whole (so plain writes; ``shown``: the name
    the user gave, for the progress bar and errors)."""
    cam = seq.camera
    P0 = np.hstack([cam.left.K, np.zeros((3, 1))])
    P1 = P0.copy()
    P1[0, 3] = -cam.left.fx * cam.baseline
    (out / "calib.txt").write_text(f"P0: {_matrix_line(P0)}\nP1: {_matrix_line(P1)}\n", encoding="utf-8")
    for sub in ("image_0", "image_1"):
        (out / sub).mkdir()
    frames = range(len(seq))
    if progress:
        from tqdm import tqdm
        frames = tqdm(frames, desc=f"writing {shown}", unit="frame")
    for i in frames:
        for sub, image in (("image_0", seq.left(i)), ("image_1", seq.right(i))):
            if not cv2.imwrite(str(out / sub / f"{i:06d}.png"), np.clip(np.rint(image), 0, 255).astype(np.uint8)):
                raise InputError("could not write the image", path=shown / sub / f"{i:06d}.png")
    (out / "times.txt").write_text("".join(f"{t:.6e}\n" for t in seq.timestamps), encoding="utf-8")
    if seq.gt_poses is not None and np.all(np.isfinite(seq.gt_poses)):
        (out / "poses.txt").write_text("".join(_matrix_line(T[:3, :]) + "\n" for T in seq.gt_poses),
                                       encoding="utf-8")
