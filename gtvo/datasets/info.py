"""What a log holds and what ``gtvo run`` would use from it (``gtvo info``).

>>> info = describe_log("run.bag")        # doctest: +SKIP
>>> print("\\n".join(info.lines()))       # doctest: +SKIP
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from gtvo.core.camera import StereoCamera
from gtvo.datasets.bag_types import GROUND_TRUTH_TYPES
from gtvo.errors import InputError


@dataclass
class LogInfo:
    """A log's contents and the sequence ``gtvo run`` would read from it.

    Attributes:
        path: the log (folder, ``.bag`` file or ROS2 bag folder).
        format: a name of :data:`gtvo.datasets.FORMATS` (the reader that opened it).
        topics: for bags, every topic as ``{name, msgtype, count, rate_hz}`` (rate = count over
            the bag's duration); empty for folders.
        usable: True when ``gtvo run`` could open it (with the options given).
        problem: the one-line reason when it could not (``gtvo run``'s error).
        kind, frames, camera, ground_truth: the sequence ``gtvo run`` would use.
        topics_used, calibration, unpaired: for bags, the image topics, the calibration's source
            and the image messages that found no partner.
        wheel_odometry: the wheel odometry ``gtvo run`` would read (its source, kind, readings and
            time span), or None (docs/wheel_odometry.md).
        imu: the IMU ``gtvo run`` would read (its source file or topic, readings, rate, time span and
            where its noise model and extrinsic came from), or None (docs/imu.md).
    """

    path: str
    format: str
    topics: list[dict[str, Any]] = field(default_factory=list)
    usable: bool = False
    problem: str | None = None
    kind: str | None = None
    frames: int | None = None
    duration_s: float | None = None
    camera: str | None = None
    ground_truth: bool = False
    topics_used: str | None = None
    calibration: str | None = None
    unpaired: dict[str, int] = field(default_factory=dict)
    wheel_odometry: str | None = None
    imu: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return asdict(self)

    def lines(self) -> list[str]:
        """The text ``gtvo info`` prints."""
        out = [f"{self.path}: {self.format}"]
        if self.topics:
            width = max(len(t["name"]) for t in self.topics)
            out.append(f"  {'topic':<{width}}  {'type':<34} {'count':>7}  rate")
            for t in self.topics:
                rate = "-" if t["rate_hz"] is None else f"{t['rate_hz']:.2f} Hz"
                out.append(f"  {t['name']:<{width}}  {t['msgtype']:<34} {t['count']:>7}  {rate}")
        if not self.usable:
            out.append(f"gtvo run would fail: {self.problem}")
            return out
        out.append(f"gtvo run would use: {self.kind}, {self.frames} frames over {self.duration_s:.3f} s")
        if self.topics_used:
            out.append(f"  topics       {self.topics_used}")
            out.append(f"  calibration  {self.calibration}")
            out.append("  unpaired     " + ", ".join(f"{k}: {v}" for k, v in self.unpaired.items()))
        out.append(f"  camera       {self.camera}")
        out.append(f"  ground truth {'yes' if self.ground_truth else 'no'}")
        if self.wheel_odometry is not None:
            out.append(f"  wheels       {self.wheel_odometry}")
        if self.imu is not None:
            out.append(f"  imu          {self.imu}")
        poses = [t["name"] for t in self.topics if t["msgtype"] in GROUND_TRUTH_TYPES]
        if poses and not self.ground_truth:
            out.append(f"  pose topics  {', '.join(poses)} (--ground-truth-topic)")
        return out


def describe_log(path: str | Path, format: str = "auto", **options: Any) -> LogInfo:
    """Describe a log: a bag's topics (read from its index, no message read) and, for any log, the
    sequence :func:`gtvo.datasets.open_sequence` makes of it with ``options`` (which reads every
    image message's header once); a log ``gtvo run`` could not open gets its ``problem``.

    Raises:
        InputError: the log cannot be read at all (missing, truncated or corrupt bag, unknown layout).
    """
    from gtvo.datasets import detect_format, open_sequence  # noqa: PLC0415
    from gtvo.datasets.bag_stream import bag_location, open_reader  # noqa: PLC0415
    from gtvo.datasets.bag_topics import topic_summaries  # noqa: PLC0415

    where = Path(path)
    kind = detect_format(where) if format == "auto" else format
    info = LogInfo(path=str(where), format=kind)
    if kind == "bag":
        reader = open_reader(where)
        try:
            info.topics = [asdict(t) for t in topic_summaries(reader)]
        finally:
            reader.close()
        info.path = str(bag_location(where))
    try:
        seq = open_sequence(where, format=kind, **options)  # type: ignore[arg-type]
    except InputError as exc:
        info.problem = str(exc)
        return info
    info.usable, info.kind, info.frames = True, seq.kind, len(seq)
    info.duration_s = float(seq.timestamps[-1] - seq.timestamps[0])
    cam = seq.pinhole
    info.camera = (f"{cam.width}x{cam.height} fx {cam.fx:.6g} fy {cam.fy:.6g} cx {cam.cx:.6g} cy {cam.cy:.6g}"
                   + (f" baseline {seq.camera.baseline:.6g} m" if isinstance(seq.camera, StereoCamera) else ""))
    info.ground_truth = seq.has_ground_truth
    wheels = seq.wheel_odometry
    if wheels is not None:
        info.wheel_odometry = (f"{wheels.source}: {wheels.kind}, {len(wheels)} readings over "
                               f"{wheels.times[0]:.3f}..{wheels.times[-1]:.3f} s")
    imu = seq.imu
    if imu is not None:
        info.imu = (f"{imu.source}: {len(imu)} readings at {imu.rate_hz:.4g} Hz over {imu.times[0]:.3f}.."
                    f"{imu.times[-1]:.3f} s; noise {imu.noise.source}; T_cam_imu {imu.extrinsic_source or 'given'}")
    if getattr(seq, "topics", None) is not None:
        info.topics_used = str(seq.topics)  # type: ignore[attr-defined]
        info.calibration = seq.calibration_source  # type: ignore[attr-defined]
        info.unpaired = dict(seq.unpaired)  # type: ignore[attr-defined]
    return info
