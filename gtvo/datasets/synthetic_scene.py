"""The synthetic room: procedural face textures and exact ray casting (:class:`SyntheticScene`).

The scene is a closed room (an axis-aligned box seen from inside) holding a few axis-aligned boxes.
Every face carries its own procedural texture: smooth value noise summed over octaves plus
soft-edged blobs, band-limited so that the rendered images are well sampled and follow the
bilinear interpolation model that direct methods assume. Rendering is exact ray casting: each
pixel's ray (pixel centres at integer ``(u, v)``, docs/conventions.md) is intersected with the
room and the boxes analytically, the nearest hit gives the exact depth ``z`` and the texture value
at the hit's 2-D face coordinates. The sequence built on it: :mod:`gtvo.datasets.synthetic`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]

#: Camera height above the ground (m) and the room's height (m); the world y axis points down.
CAMERA_HEIGHT_M = 1.4
ROOM_HEIGHT_M = 3.4
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
