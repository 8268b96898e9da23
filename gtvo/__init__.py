"""gtvo: a factor-graph backend for direct stereo visual odometry on GTSAM.

Data flows one way: readers (:mod:`gtvo.datasets`) -> frames and camera
(:mod:`gtvo.camera`, :mod:`gtvo.image`) -> front end -> factors (:mod:`factors`) ->
solvers -> outputs (:mod:`gtvo.trajectory`, plots, point clouds).
Conventions (frames, pixel centres, Pose3 tangent order): ``docs/conventions.md``.
"""

__version__ = "0.1.0"
