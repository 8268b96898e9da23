"""The ROS message types and the matching tolerances of the bag reader (:mod:`gtvo.datasets.bag`)."""

from __future__ import annotations

import re

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
GROUND_TRUTH_TYPES = ("geometry_msgs/msg/PoseStamped", "nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped")
#: Left/right header stamps closer than this (s) form a stereo pair.
STEREO_TOLERANCE_S = 0.005
#: Colour/depth header stamps closer than this (s) form an RGB-D pair (TUM's associate.py).
RGBD_TOLERANCE_S = 0.02
#: Ground truth: nearest sample within this (s), interpolated across gaps up to GT_MAX_GAP_S.
GT_TOLERANCE_S = 0.02
GT_MAX_GAP_S = 0.1
#: Name pairs that make two image topics a stereo pair (left token, right token).
STEREO_TOKENS = (("left", "right"), ("cam0", "cam1"), ("infra1", "infra2"))
#: An image topic whose name matches carries rectified images (``image_rect``, ``/rectified/``).
RECTIFIED_TOPIC = re.compile(r"(^|[/_])rect")
#: Messages read ahead and kept for later frames at most; a stream jumps rather than reads further.
MAX_BUFFERED = 16
MAX_READ_AHEAD = 32
