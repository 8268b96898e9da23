"""Writing small ROS1 / ROS2 bags for the bag reader's tests (and the memory benchmark): the writer
is :mod:`gtvo.datasets.bag_writer` (``gtvo synthetic --bag`` writes with it too)."""

from gtvo.datasets.bag_writer import BagWriter, stamp_from_text

__all__ = ["BagWriter", "stamp_from_text"]
