"""The one lazy sequence type every reader returns (and the synthetic generator too).

A :class:`Sequence` knows its camera, timestamps and optional ground truth up front, and loads
images only when asked (``seq.left(i)``), so a 4000-frame log costs nothing to open.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator, Literal

import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.image import as_float_gray
from gtvo.datasets.imu import ImuMeasurements
from gtvo.datasets.wheel import WheelOdometry
from gtvo.errors import InputError

#: Image ``i`` of a sequence: float32 gray for left and right as a reader makes it (or any image
#: :func:`gtvo.core.image.to_float_gray` converts: :class:`Sequence` converts it, once), metres for depth.
ImageLoader = Callable[[int], NDArray]
SequenceKind = Literal["stereo", "rgbd"]


@dataclass(frozen=True)
class Frame:
    """One time step: index, timestamp (s) and its images, loaded when the frame is made.

    ``left`` and ``right`` are float32 gray images (:func:`gtvo.core.image.to_float_gray`),
    converted once where they were read (:meth:`Sequence.left`); the odometry uses them as they
    are. Images of another type given here are converted once, now.
    """

    index: int
    timestamp: float
    left: NDArray[np.float32]
    right: NDArray[np.float32] | None = None
    depth: NDArray[np.float32] | None = None  # metres, 0 = no measurement (RGB-D)
    gt_T_world_cam: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "left", as_float_gray(self.left, f"frame {self.index} left image"))
        if self.right is not None:
            object.__setattr__(self, "right", as_float_gray(self.right, f"frame {self.index} right image"))


@dataclass
class Sequence:
    """A logged stereo (or RGB-D) track.

    Attributes:
        name: a short name (folder name).
        kind: ``"stereo"`` (left/right rectified pair) or ``"rgbd"`` (image + metric depth).
        camera: for stereo a :class:`StereoCamera` (rectified); for RGB-D a :class:`PinholeCamera`.
        timestamps: (N,) seconds, strictly increasing.
        gt_poses: optional (N, 4, 4) ground-truth ``T_world_cam`` of the left camera, NaN-filled
            rows where no ground truth covers a frame.
        source: the folder it was read from (None for generated sequences).
        frame_names: (N,) a name per frame for error messages (e.g. the left image's path).
        wheel_odometry: the robot's raw wheel odometry in the same clock, when logged
            (:class:`gtvo.datasets.wheel.WheelOdometry`; docs/wheel_odometry.md); kept whole by
            :meth:`truncated` and :meth:`subsampled`.
        imu: the IMU's readings in the same clock, its noise model and its pose on the left camera,
            when logged (:class:`gtvo.datasets.imu.ImuMeasurements`; docs/imu.md); kept whole like
            the wheel odometry.
    """

    name: str
    kind: SequenceKind
    camera: StereoCamera | PinholeCamera
    timestamps: NDArray[np.float64]
    load_left: ImageLoader
    load_right: ImageLoader | None = None
    load_depth: ImageLoader | None = None
    gt_poses: NDArray[np.float64] | None = None
    source: Path | None = None
    frame_names: list[str] = field(default_factory=list)
    wheel_odometry: WheelOdometry | None = None
    imu: ImuMeasurements | None = None

    def __post_init__(self) -> None:
        self.timestamps = np.asarray(self.timestamps, dtype=np.float64).reshape(-1)
        where = self.source if self.source is not None else self.name
        if self.timestamps.size == 0:
            raise InputError("empty sequence: no frames", path=where)
        if not np.all(np.isfinite(self.timestamps)):
            raise InputError("timestamps contain NaN or infinite values", path=where)
        if self.timestamps.size > 1 and np.any(np.diff(self.timestamps) <= 0):
            k = int(np.argmax(np.diff(self.timestamps) <= 0))
            raise InputError(f"timestamps are not strictly increasing at frame {k + 1}", path=where)
        if self.kind == "stereo" and (self.load_right is None or not isinstance(self.camera, StereoCamera)):
            raise InputError("a stereo sequence needs right images and a StereoCamera", path=where)
        if self.kind == "rgbd" and self.load_depth is None:
            raise InputError("an RGB-D sequence needs depth images", path=where)
        if self.gt_poses is not None:
            self.gt_poses = np.asarray(self.gt_poses, dtype=np.float64)
            if self.gt_poses.shape != (len(self), 4, 4):
                raise InputError(f"ground truth has shape {self.gt_poses.shape}, expected ({len(self)}, 4, 4)",
                                 path=where)
        if not self.frame_names:
            self.frame_names = [f"{self.name}[{i}]" for i in range(len(self))]

    def __len__(self) -> int:
        return int(self.timestamps.size)

    @property
    def pinhole(self) -> PinholeCamera:
        """The (left) pinhole camera."""
        return self.camera.left if isinstance(self.camera, StereoCamera) else self.camera

    @property
    def has_ground_truth(self) -> bool:
        """True when at least one frame has a ground-truth pose."""
        return self.gt_poses is not None and bool(np.any(np.isfinite(self.gt_poses[:, 0, 0])))

    def left(self, i: int) -> NDArray[np.float32]:
        """Left (or RGB-D colour, as gray) image ``i``, float32 gray (:meth:`_gray`)."""
        return self._gray(self._checked(self.load_left(i), i, "left"), i, "left")

    def right(self, i: int) -> NDArray[np.float32]:
        """Right image ``i`` (stereo only), float32 gray (:meth:`_gray`)."""
        if self.load_right is None:
            raise InputError(f"sequence {self.name} has no right images")
        return self._gray(self._checked(self.load_right(i), i, "right"), i, "right")

    def depth(self, i: int) -> NDArray[np.float32]:
        """Metric depth image ``i`` (RGB-D only), metres, 0 where unknown."""
        if self.load_depth is None:
            raise InputError(f"sequence {self.name} has no depth images")
        return self._checked(self.load_depth(i), i, "depth")

    def frame(self, i: int) -> Frame:
        """Frame ``i`` with its images loaded."""
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} out of range 0..{len(self) - 1}")
        gt = None
        if self.gt_poses is not None and np.isfinite(self.gt_poses[i, 0, 0]):
            gt = self.gt_poses[i]
        return Frame(
            index=i,
            timestamp=float(self.timestamps[i]),
            left=self.left(i),
            right=self.right(i) if self.kind == "stereo" else None,
            depth=self.depth(i) if self.kind == "rgbd" else None,
            gt_T_world_cam=gt,
        )

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def truncated(self, max_frames: int | None) -> "Sequence":
        """The first ``max_frames`` frames (the same sequence when None)."""
        if max_frames is None or max_frames >= len(self):
            return self
        if max_frames < 1:
            raise InputError(f"--max-frames must be >= 1, got {max_frames}")
        return self._select(list(range(int(max_frames))))

    def subsampled(self, step: int) -> "Sequence":
        """Every ``step``-th frame (0, step, 2 step, ...): the same log at a lower frame rate."""
        if step < 1:
            raise InputError(f"frame step must be >= 1, got {step}")
        if step == 1:
            return self
        return self._select(list(range(0, len(self), int(step))))

    def _select(self, idx: list[int]) -> "Sequence":
        """The frames ``idx`` (increasing) as a sequence of their own, of the same class (a subclass
        slices its own per-frame fields on top of this)."""

        def pick(loader: ImageLoader | None) -> ImageLoader | None:
            return None if loader is None else (lambda i: loader(idx[i]))

        return replace(self, timestamps=self.timestamps[idx], load_left=pick(self.load_left),
                       load_right=pick(self.load_right), load_depth=pick(self.load_depth),
                       gt_poses=None if self.gt_poses is None else self.gt_poses[idx],
                       frame_names=[self.frame_names[i] for i in idx])

    def _gray(self, img: NDArray, i: int, which: str) -> NDArray[np.float32]:
        """The loader's image as float32 gray: the image itself when the loader converted it (every
        reader's does, :func:`gtvo.core.image.to_float_gray`), else converted here, once."""
        try:
            return as_float_gray(img, f"{which} image")
        except InputError as exc:
            raise InputError(str(exc), path=self.frame_names[i] if i < len(self.frame_names) else None) from None

    def _checked(self, img: NDArray, i: int, which: str) -> NDArray[np.float32]:
        h, w = self.pinhole.height, self.pinhole.width
        if img.shape[:2] != (h, w):
            raise InputError(f"{which} image is {img.shape[1]}x{img.shape[0]}, the camera expects {w}x{h}",
                             path=self.frame_names[i] if i < len(self.frame_names) else None)
        return img
