"""Frames streamed out of a bag: one pass in time order that jumps back only when asked for an
earlier frame (:class:`BagStream`), image decoding (:func:`decode_image`, :func:`depth_metres`)
and the lazy per-frame loader a :class:`gtvo.datasets.sequence.Sequence` calls (:class:`BagImageLoader`)."""

from __future__ import annotations

import bisect
import sqlite3
import struct
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.core.image import to_float_gray

from gtvo.datasets.bag_types import COMPRESSED, MAX_BUFFERED, MAX_READ_AHEAD


def bag_location(path: Path) -> Path:
    """What ``rosbags`` opens: the ``.bag`` file, or the ROS2 folder (also for a file inside it)."""
    return path.parent if path.is_file() and path.suffix in (".db3", ".mcap") else path


def reader_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError  # noqa: PLC0415
    from rosbags.rosbag1 import ReaderError as Reader1Error  # noqa: PLC0415
    from rosbags.rosbag2 import ReaderError as Reader2Error  # noqa: PLC0415
    from rosbags.serde import SerdeError  # noqa: PLC0415

    return (AnyReaderError, Reader1Error, Reader2Error, SerdeError, sqlite3.Error, struct.error, EOFError,
            OSError, ValueError, KeyError, IndexError, AssertionError)


def open_reader(path: Path) -> Any:
    """An open ``rosbags.highlevel.AnyReader`` on ``path``; any failure is one InputError naming it."""
    from rosbags.highlevel import AnyReader  # noqa: PLC0415
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    where = bag_location(path)
    if not where.exists():
        raise InputError("bag not found", path=where)
    try:
        reader = AnyReader([where], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except reader_errors() as exc:
        raise InputError(f"cannot read bag (truncated or corrupt?): {first_line(exc)}", path=where) from None
    return reader


def first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{exc.__class__.__name__}: {text[0]}" if text else exc.__class__.__name__


class BagStream:
    """Serves message ``k`` of a topic (in log-time order) from one stream over the bag.

    Asked in increasing order (a run), it reads the bag once; messages of other wanted topics met
    on the way are kept (at most :data:`MAX_BUFFERED`) until asked for. A message behind the
    stream, or more than :data:`MAX_READ_AHEAD` messages ahead, restarts the stream at its log time.
    """

    def __init__(self, path: Path, log_ns: dict[str, list[int]], wanted: dict[str, set[int]]):
        self.path = path
        self.log_ns = log_ns
        self.wanted = wanted
        self._reader: Any = None
        self._messages: Iterator[tuple[Any, int, bytes]] | None = None
        self._next: dict[str, int] = {}
        self._buffer: dict[tuple[str, int], bytes] = {}

    @property
    def reader(self) -> Any:
        """The open ``AnyReader`` (opened on first use)."""
        if self._reader is None:
            self._reader = open_reader(self.path)
        return self._reader

    def get(self, topic: str, k: int) -> bytes:
        """The raw (serialised) message ``k`` of ``topic``."""
        key = (topic, k)
        if key in self._buffer:
            return self._buffer.pop(key)
        position = self._next.get(topic, -1)
        if self._messages is None or position > k or k - position > MAX_READ_AHEAD:
            self._restart(self.log_ns[topic][k])
        try:
            for conn, _log, raw in self._messages:  # type: ignore[union-attr]
                j = self._next[conn.topic]
                self._next[conn.topic] = j + 1
                if conn.topic == topic and j == k:
                    return raw
                if j in self.wanted[conn.topic]:
                    self._keep((conn.topic, j), raw)
        except reader_errors() as exc:
            raise InputError(f"cannot read bag (truncated or corrupt?): {first_line(exc)}", path=self.path) from None
        self._messages = None
        raise InputError(f"message {k} of {topic} not found in the bag", path=self.path)

    def _restart(self, start_ns: int) -> None:
        topics = set(self.log_ns)
        connections = [c for c in self.reader.connections if c.topic in topics]
        self._next = {t: bisect.bisect_left(times, start_ns) for t, times in self.log_ns.items()}
        self._buffer.clear()
        self._messages = iter(self.reader.messages(connections=connections, start=start_ns))

    def _keep(self, key: tuple[str, int], raw: bytes) -> None:
        self._buffer[key] = bytes(raw)
        while len(self._buffer) > MAX_BUFFERED:
            self._buffer.pop(next(iter(self._buffer)))


# --------------------------------------------------------------------------------------------
# decoding images

def decode_image(msg: Any, msgtype: str) -> NDArray:
    """The pixels of a ``sensor_msgs/Image`` (mono8, mono16, rgb8, bgr8, rgba8, bgra8, 8UC1,
    16UC1, 32FC1) or ``CompressedImage`` (png, jpeg) as stored: gray (H, W), BGR (H, W, 3),
    uint16 or float32. InputError (message only; the caller names the file) for anything else."""
    if msgtype == COMPRESSED:
        fmt = str(msg.format).lower()
        if "compresseddepth" in fmt or not any(k in fmt for k in ("png", "jpeg", "jpg")):
            raise InputError(f"unknown compressed image format {msg.format!r} (png or jpeg)")
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None or image.size == 0:
            raise InputError(f"cannot decode the {msg.format!r} compressed image (corrupt data)")
        return image
    encoding = str(msg.encoding).lower()
    layouts = {"mono8": (np.uint8, 1), "8uc1": (np.uint8, 1), "mono16": (np.uint16, 1), "16uc1": (np.uint16, 1),
               "32fc1": (np.float32, 1), "rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4),
               "bgra8": (np.uint8, 4)}
    if encoding not in layouts:
        raise InputError(f"unknown image encoding {msg.encoding!r} (mono8, mono16, rgb8, bgr8, 16UC1, 32FC1)")
    dtype, channels = layouts[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    item = np.dtype(dtype).itemsize
    if h < 1 or w < 1 or step < w * channels * item or data.size < h * step:
        raise InputError(f"{encoding} image {w}x{h} with step {step} needs {h * step} bytes, has {data.size}")
    rows = data[: h * step].reshape(h, step)[:, : w * channels * item]
    order = ">" if int(msg.is_bigendian) else "<"
    image = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order) if item > 1 else dtype)
    image = image.reshape(h, w, channels).astype(dtype) if channels > 1 else image.reshape(h, w).astype(dtype)
    if encoding.startswith("rgb"):
        image = image[..., [2, 1, 0]]
    return image


def depth_metres(image: NDArray, encoding: str) -> NDArray[np.float32]:
    """A depth image as metres, 0 where unknown: 16-bit values are millimetres, float values metres."""
    if image.ndim != 2 or image.dtype not in (np.uint16, np.float32):
        raise InputError(f"depth image must be 16UC1 (mm) or 32FC1 (m), got {encoding} "
                         f"({image.dtype}, shape {image.shape})")
    if image.dtype == np.uint16:
        return image.astype(np.float32) / np.float32(1000.0)
    out = image.astype(np.float32, copy=True)
    out[~np.isfinite(out)] = 0.0
    return out


class BagImageLoader:
    """Loads frame ``i`` of one topic: ``stream.get(topic, ordinals[i])``, decoded, converted to
    float gray (or metres for ``depth``) and warped when the calibration rectifies."""

    def __init__(self, stream: BagStream, topic: str, msgtype: str, ordinals: list[int], names: list[str],
                 depth: bool = False, warp: Any = None):
        self.stream, self.topic, self.msgtype = stream, topic, msgtype
        self.ordinals, self.names, self.depth, self.warp = ordinals, names, depth, warp

    def __call__(self, i: int) -> NDArray[np.float32]:
        where = self.names[i]
        try:
            msg = self.stream.reader.deserialize(self.stream.get(self.topic, self.ordinals[i]), self.msgtype)
            image = decode_image(msg, self.msgtype)
            encoding = getattr(msg, "encoding", getattr(msg, "format", "?"))
            if self.depth:
                return depth_metres(image, str(encoding))
            gray = to_float_gray(image, name=f"{self.topic} image")
        except InputError as exc:
            raise InputError(str(exc), path=where) from None
        except reader_errors() as exc:
            raise InputError(f"cannot decode message: {first_line(exc)}", path=where) from None
        return gray if self.warp is None else self.warp(gray)


# --------------------------------------------------------------------------------------------
# the sequence
