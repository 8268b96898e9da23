"""A bag's topics and which of them a run uses: summaries per topic, the stereo / RGB-D pair
candidates by name, and the choice ``gtvo run`` makes (or the error listing the candidates)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


from gtvo.errors import InputError

from gtvo.datasets.bag_types import CAMERA_INFO, COMPRESSED, IMAGE, STEREO_TOKENS


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: name, ROS message type, message count and mean rate over the bag (Hz)."""

    name: str
    msgtype: str
    count: int
    rate_hz: float | None


def topic_summaries(reader: Any) -> list[TopicSummary]:
    """Every topic of an open reader, sorted by name (rate = count / the bag's duration)."""
    seconds = max(reader.duration, 0) * 1e-9
    out = []
    for name, info in sorted(reader.topics.items()):
        count = int(info.msgcount)
        rate = (count - 1) / seconds if seconds > 0 and count > 1 else None
        out.append(TopicSummary(name, str(info.msgtype), count, rate))
    return out


# --------------------------------------------------------------------------------------------
# choosing the topics

@dataclass(frozen=True)
class TopicChoice:
    """What a run uses: ``kind`` and the two image topics (left, right) or (colour, depth)."""

    kind: str
    first: str
    second: str

    def __str__(self) -> str:
        names = ("left", "right") if self.kind == "stereo" else ("colour", "depth")
        return f"{self.kind}: {names[0]} {self.first}, {names[1]} {self.second}"


def stereo_candidates(image_topics: list[str]) -> list[TopicChoice]:
    """Pairs of image topics whose names differ by a left/right token (:data:`STEREO_TOKENS`)."""
    found = []
    for topic in image_topics:
        for left, right in STEREO_TOKENS:
            k = topic.rfind(left)
            if k >= 0:
                other = topic[:k] + right + topic[k + len(left):]
                if other in image_topics:
                    found.append(TopicChoice("stereo", topic, other))
    return found


def rgbd_candidates(image_topics: list[str]) -> list[TopicChoice]:
    """(colour, depth) pairs: every non-stereo image topic with every topic named ``*depth*``."""
    stereo = {t for c in stereo_candidates(image_topics) for t in (c.first, c.second)}
    depth = [t for t in image_topics if "depth" in t.lower()]
    colour = [t for t in image_topics if t not in depth and t not in stereo]
    return [TopicChoice("rgbd", c, d) for c in colour for d in depth]


def choose_topics(topics: list[TopicSummary], left: str | None = None, right: str | None = None,
                  depth: str | None = None, where: Path | str = "") -> TopicChoice:
    """The image topics a run uses (module docstring); InputError listing the candidates when the
    choice is missing, ambiguous or names a topic the bag does not have."""
    images = [t.name for t in topics if t.msgtype in (IMAGE, COMPRESSED) and t.count > 0]
    if not images:
        listed = ", ".join(f"{t.name} ({t.msgtype})" for t in topics) or "none"
        raise InputError(f"no image topic (sensor_msgs/Image or CompressedImage) in the bag; topics: {listed}",
                         path=where)
    for flag, name in (("--left-topic", left), ("--right-topic", right), ("--depth-topic", depth)):
        if name is not None and name not in images:
            raise InputError(f"{flag} {name}: no such image topic in the bag; image topics: {', '.join(images)}",
                             path=where)
    if depth is not None and right is not None:
        raise InputError("give --right-topic (stereo) or --depth-topic (RGB-D), not both", path=where)
    if left is not None and (right is not None or depth is not None):
        return TopicChoice("stereo" if right is not None else "rgbd", left, right or depth)  # type: ignore[arg-type]
    candidates = stereo_candidates(images) or rgbd_candidates(images)
    if depth is not None:
        candidates = [c for c in rgbd_candidates(images) if c.second == depth]
    candidates = [c for c in candidates if (left is None or c.first == left) and (right is None or c.second == right)]
    if len(candidates) == 1:
        return candidates[0]
    listed = "; ".join(str(c) for c in candidates) if candidates else f"none among {', '.join(images)}"
    raise InputError(f"{len(candidates)} usable image topic pairs ({listed}): choose with --left-topic and "
                     f"--right-topic (--depth-topic for RGB-D)", path=where)


def camera_info_topic(image_topic: str, topics: list[TopicSummary]) -> str | None:
    """The ``CameraInfo`` topic in the image topic's namespace (``/ns/left/image_raw[/compressed]``
    -> ``/ns/left/camera_info``), or None."""
    infos = {t.name for t in topics if t.msgtype == CAMERA_INFO}
    parts = image_topic.rstrip("/").split("/")
    if parts[-1] == "compressed":
        parts = parts[:-1]
    while len(parts) > 1:
        parts = parts[:-1]
        candidate = "/".join(parts) + "/camera_info"
        if candidate in infos:
            return candidate
    return None


# --------------------------------------------------------------------------------------------
# header stamps and the one pass over the bag on open
