"""A deterministic synthetic stereo sequence with exact depth and poses (the demo's default data).

The scene (a textured room rendered by exact ray casting) is :mod:`gtvo.datasets.synthetic_scene`;
this module moves a stereo rig through it and serves the frames as a lazy sequence.

Public API:

* :func:`make_synthetic_sequence` -> :class:`SyntheticSequence` (a :class:`gtvo.datasets.sequence.Sequence`
  of kind ``"stereo"`` with ground truth, rendered lazily and LRU-cached), whose extra accessors
  are :meth:`SyntheticSequence.true_depth` (exact depth maps), :attr:`SyntheticSequence.affine_left`
  / :attr:`SyntheticSequence.affine_right` (the known brightness change) and
  :attr:`SyntheticSequence.scene` (to render any other view).
* :func:`synthetic_trajectory`; the scene: :func:`gtvo.datasets.synthetic_scene.make_scene`,
  :class:`gtvo.datasets.synthetic_scene.SyntheticScene` (``render``).
* :func:`write_sequence_kitti`: any stereo sequence to the KITTI odometry layout.

The maths and the measured limits of exactness: docs/synthetic.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from gtvo.core.atomic import atomic_dir
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError, show
from gtvo.datasets.imu_files import write_imu_files
from gtvo.datasets.sequence import Sequence
from gtvo.datasets.synthetic_imu import ImuSimulation, simulate_imu
from gtvo.datasets.synthetic_robot import WheelSimulation, ground_robot_trajectory, simulate_sequence_wheels, \
    wheel_config_yaml
from gtvo.datasets.synthetic_scene import Rendering, SyntheticScene, make_scene
from gtvo.datasets.wheel_files import WHEEL_CSV, write_wheel_csv

FloatArray = NDArray[np.float64]
Motion = Literal["forward", "loop", "turn", "ground", "swerve"]

#: Frame rate of the generated sequences (Hz), KITTI's.
FRAME_RATE_HZ = 10.0
#: Default stereo baseline (m).
DEFAULT_BASELINE = 0.5
#: The ``"turn"`` motion: straight for this many frames, then a constant yaw rate (deg per frame,
#: to the right; 30 deg/s at 10 Hz, a car's tight urban turn).
TURN_START_FRAME = 8
TURN_DEG_PER_FRAME = 3.0


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
    ``"ground"``: a ground robot's slalom in the plane, the camera level on the base
    (:func:`gtvo.datasets.synthetic_robot.ground_robot_trajectory`).
    ``"swerve"``: ``"forward"``'s path with fast turns: the yaw swings by :data:`SWERVE_YAW_DEG`
    with a period of :data:`SWERVE_PERIOD_S` (peak rate about 47 deg/s, 4.7 deg per frame at
    10 Hz), the pitch and roll wobbles of ``"forward"``: smooth, so an IMU can be simulated along it
    (:func:`synthetic_poses_at`).
    """
    n = int(n_frames)
    if n < 1:
        raise InputError(f"n_frames must be >= 1, got {n_frames}")
    if not (np.isfinite(step_m) and step_m > 0):
        raise InputError(f"step_m must be a finite positive number, got {show(step_m)}")
    dt = 1.0 / float(frame_rate_hz)
    if motion == "ground":
        return ground_robot_trajectory(n, step_m)
    if motion == "turn":
        deg = np.pi / 180.0
        yaw = TURN_DEG_PER_FRAME * deg * np.maximum(np.arange(n) - TURN_START_FRAME, 0)
        heading = np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], axis=1)
        pos = np.concatenate([np.zeros((1, 3)), np.cumsum(step_m * heading[1:], axis=0)])
        return _poses(pos, yaw, np.zeros(n), np.zeros(n))
    if motion not in SMOOTH_MOTIONS:
        raise InputError(f"motion must be 'forward', 'loop', 'turn', 'ground' or 'swerve', got {motion!r}")
    return _poses(*_smooth_motion(np.arange(n) * dt, 2 * np.pi * np.arange(n) / n, n, motion, step_m, dt))


#: The motions whose poses are smooth functions of time (:func:`synthetic_poses_at`).
SMOOTH_MOTIONS: tuple[str, ...] = ("forward", "loop", "swerve")
#: The ``"swerve"`` motion's yaw swing (deg) and period (s).
SWERVE_YAW_DEG = 30.0
SWERVE_PERIOD_S = 4.0


def _smooth_motion(t: FloatArray, s: FloatArray, n: int, motion: str, step_m: float,
                   dt: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(positions, yaw, pitch, roll)`` of a smooth motion at the times ``t`` (``s``: the loop's
    angle at them, ``2 pi t / (n dt)``)."""
    deg = np.pi / 180.0
    if motion in ("forward", "swerve"):
        v = step_m / dt
        pos = np.stack([0.25 * np.sin(2 * np.pi * t / 5.0), 0.04 * np.sin(2 * np.pi * t / 2.9), v * t], axis=1)
        yaw = 4.0 * deg * np.sin(2 * np.pi * t / 6.0)
        if motion == "swerve":
            yaw = SWERVE_YAW_DEG * deg * np.sin(2 * np.pi * t / SWERVE_PERIOD_S)
        pitch = 1.5 * deg * np.sin(2 * np.pi * t / 3.7)
        roll = 1.0 * deg * np.sin(2 * np.pi * t / 4.3)
        return pos, yaw, pitch, roll
    period = n * dt
    a, b = 1.0, 0.5  # unit ellipse, scaled to the wanted perimeter (Ramanujan's formula)
    perimeter = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
    a_z = n * step_m / perimeter
    k = max(1, int(round(period / 6.0)))  # wobble cycles per loop: about 1/6 Hz
    rate_cap = 5.0 * deg / (2 * np.pi * k / period)  # keep peak rates <= ~5 deg/s
    pos = np.stack([0.5 * a_z * (1 - np.cos(s)), 0.04 * np.sin(2 * k * s), a_z * np.sin(s)], axis=1)
    yaw = min(4.0 * deg, rate_cap) * np.sin(k * s)
    pitch = min(1.5 * deg, rate_cap) * np.sin(2 * k * s) / 2
    roll = min(1.0 * deg, rate_cap) * np.sin(k * s + np.sin(s))
    return pos, yaw, pitch, roll


def _poses(pos: FloatArray, yaw: FloatArray, pitch: FloatArray, roll: FloatArray) -> FloatArray:
    T = np.tile(np.eye(4), (len(pos), 1, 1))
    for i in range(len(pos)):
        T[i, :3, :3] = _rotation_ypr(yaw[i], pitch[i], roll[i])
    T[:, :3, 3] = pos
    return T


def synthetic_poses_at(times: ArrayLike, n_frames: int, motion: Motion = "forward", step_m: float = 0.15,
                       frame_rate_hz: float = FRAME_RATE_HZ) -> FloatArray:
    """``T_world_cam`` (M, 4, 4) of a smooth motion (:data:`SMOOTH_MOTIONS`) at any times (s): the
    curve :func:`synthetic_trajectory` samples at its frames (to rounding), for an IMU along it.

    Raises:
        InputError: a motion that is not smooth (``"turn"``, ``"ground"``: one arc per frame).
    """
    if motion not in SMOOTH_MOTIONS:
        raise InputError(f"motion {motion!r} is not a smooth function of time: an IMU needs one of "
                         f"{', '.join(SMOOTH_MOTIONS)}")
    n = int(n_frames)
    dt = 1.0 / float(frame_rate_hz)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    return _poses(*_smooth_motion(t, 2 * np.pi * t / (n * dt), n, motion, step_m, dt))


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
                 affine_right: FloatArray, noise_sigma: float, seed: int, supersample: int, cache_size: int,
                 right_principal_offset: tuple[float, float] = (0.0, 0.0)):
        self.scene = scene
        self.camera = camera
        dx, dy = (float(x) for x in right_principal_offset)
        c = camera.left
        #: the camera the right image is rendered with: the left intrinsics, principal point moved
        self.right_camera = replace(c, cx=c.cx + dx, cy=c.cy + dy) if (dx, dy) != (0.0, 0.0) else c
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
        for side, (T, cam) in enumerate(((T_left, self.camera.left), (T_right, self.right_camera))):
            radiance, depth, face = self.scene.render(T, cam, self.supersample)
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
        wheel_model: with wheel odometry, the calibration model that recovers the simulated error
            (:attr:`gtvo.datasets.synthetic_robot.WheelSimulation.model`; ``wheel.yaml``'s), else None.

    Exact depth is :meth:`true_depth` (not ``load_depth``, which marks RGB-D sequences), the
    surface seen by each pixel :meth:`face_ids`, and pixels away from creases and silhouettes
    :meth:`interior_mask`.
    """

    scene: SyntheticScene | None = None
    affine_left: FloatArray | None = None
    affine_right: FloatArray | None = None
    noise_sigma: float = 0.0
    wheel_model: str | None = None
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
                            supersample: int = 1, cache_size: int = 32,
                            right_principal_offset: tuple[float, float] = (0.0, 0.0),
                            wheels: WheelSimulation | None = None, imu: ImuSimulation | None = None) -> SyntheticSequence:
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
        right_principal_offset: ``(dx, dy)`` px added to the right camera's principal point when
            rendering its images (the sequence's ``camera`` stays the rectified one): a rig whose
            right image is offset by exactly ``(delta_x, delta_y) = (dx, dy)`` against its
            calibration, rendered rather than resampled (docs/window.md, "Rig calibration").
        wheels: the wheel odometry the robot logs (``Sequence.wheel_odometry``; best with
            ``motion="ground"``, docs/wheel_odometry.md).
        imu: the IMU the camera carries (``Sequence.imu``, readings from the first frame's time to
            the last's along the exact motion: :mod:`gtvo.datasets.synthetic_imu`; a smooth
            ``motion`` only, docs/imu.md).
    """
    for name, value in (("noise_sigma", noise_sigma), ("baseline", baseline)):
        if not np.isfinite(value) or value < 0 or (name == "baseline" and value == 0):
            raise InputError(f"{name} must be finite and {'positive' if name == 'baseline' else '>= 0'}, "
                             f"got {show(value)}")
    if int(supersample) < 1:
        raise InputError(f"supersample must be >= 1, got {supersample}")
    offset = tuple(float(x) for x in np.asarray(right_principal_offset, dtype=float).reshape(-1))
    if len(offset) != 2 or not all(np.isfinite(offset)):
        raise InputError(f"right_principal_offset must be two finite numbers (px), got {right_principal_offset!r}")
    camera = synthetic_camera(width, height, baseline)
    poses = synthetic_trajectory(n_frames, motion, step_m)
    right_centres = poses[:, :3, 3] + poses[:, :3, 0] * baseline
    scene = make_scene(np.concatenate([poses[:, :3, 3], right_centres]), seed)
    affine_left, affine_right = synthetic_exposures(n_frames, exposure_change)
    renderer = _FrameRenderer(scene, camera, poses, affine_left, affine_right, noise_sigma, seed, supersample,
                              max(1, int(cache_size)), (offset[0], offset[1]))
    n = poses.shape[0]
    name = f"synthetic-{motion}-seed{int(seed)}" + (f"+right-pp({offset[0]:+g},{offset[1]:+g})px" if any(offset) else "")
    times = np.arange(n) / FRAME_RATE_HZ
    wheel = None if wheels is None else simulate_sequence_wheels(times, poses, wheels, f"{name} wheels")
    imu_log = None
    if imu is not None:
        imu_log = simulate_imu(float(times[0]), float(times[-1]),
                               lambda t: synthetic_poses_at(t, n_frames, motion, step_m), imu, source=f"{name} IMU")
    return SyntheticSequence(name, "stereo", camera, times, renderer.left, renderer.right,
                             None, poses, None, [], wheel, imu_log, scene=scene, affine_left=affine_left,
                             affine_right=affine_right, noise_sigma=float(noise_sigma),
                             wheel_model=None if wheels is None else wheels.model, _renderer=renderer)


# -------------------------------------------------------------------------------------------- writer


def _matrix_line(M: ArrayLike) -> str:
    return " ".join(f"{x:.12e}" for x in np.asarray(M, dtype=np.float64).reshape(-1))


def write_sequence_kitti(seq: Sequence, folder: str | Path, progress: bool = False) -> Path:
    """Write a stereo sequence in the KITTI odometry layout, the folder as a whole.

    The files are written into a new folder that replaces ``folder`` when complete
    (:func:`gtvo.core.atomic.atomic_dir`): an interrupted write leaves the old folder intact, and a
    shorter sequence leaves none of a longer one's frames behind. An existing ``folder`` is
    replaced only when it is empty or was written here (it carries ``gtvo.core.atomic.DIR_MARKER``)
    and holds nothing else; a real dataset folder or one with other files is refused
    (:class:`InputError`), never overwritten.

    ``calib.txt`` (``P0:``/``P1:`` 3x4 rows, ``P1[0,3] = -fx * baseline``), ``image_0/`` and
    ``image_1/`` (8-bit PNG, ``NNNNNN.png``, intensities rounded and clipped to 0..255),
    ``times.txt`` and, when every frame has ground truth, ``poses.txt`` (3x4 row-major
    ``T_world_cam`` of the left camera); with wheel odometry ``wheel_odometry.csv`` and ``wheel.yaml``,
    the config's ``wheel:`` section that reads it (``gtvo run --config wheel.yaml``).
    """
    if seq.kind != "stereo" or not isinstance(seq.camera, StereoCamera):
        raise InputError(f"sequence {seq.name} is not stereo; the KITTI layout needs a stereo pair")
    with atomic_dir(folder, KITTI_LAYOUT_ENTRIES, "gtvo synthetic") as tmp:
        _write_kitti_files(seq, tmp, Path(folder), progress)
    return Path(folder)


#: What :func:`write_sequence_kitti` writes into its folder (and may therefore replace there).
KITTI_LAYOUT_ENTRIES = frozenset({"calib.txt", "times.txt", "poses.txt", "image_0", "image_1", WHEEL_CSV, "wheel.yaml",
                                  "imu0"})


def _write_kitti_files(seq: Sequence, out: Path, shown: Path, progress: bool) -> None:
    """The files of :func:`write_sequence_kitti` into ``out``, a fresh temporary folder that
    :func:`gtvo.core.atomic.atomic_dir` swaps in as a whole (so plain writes; ``shown``: the name
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
    if seq.wheel_odometry is not None:
        write_wheel_csv(seq.wheel_odometry, out / WHEEL_CSV)
        model = getattr(seq, "wheel_model", None) or "diff_drive"
        (out / "wheel.yaml").write_text(wheel_config_yaml(seq.wheel_odometry, model), encoding="utf-8")
    if seq.imu is not None:
        write_imu_files(seq.imu, out)
