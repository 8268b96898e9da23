"""The configuration tree of a VO run: :class:`OdometryConfig` and the settings it nests.

One place for every setting of a run (KISS-ICP's single config), one frozen dataclass per
component, each field's default and allowed range declared once beside it
(:func:`gtvo.core.settings.setting`)::

    OdometryConfig
      mode                 "window" | "track"
      solver               SolverConfig (tracker, window)
      frontend             FrontendConfig (points_per_keyframe, points: PointSelectionConfig,
                                           stereo: StereoSearchConfig, depth_sigma_model)
      keyframes            gtvo.frontend.keyframes.KeyframeConfig
      tracking             gtvo.frontend.tracking.TrackingConfig
      window               gtvo.window.WindowConfig
      flow_fallback        gtvo.frontend.flow_pose.FlowPoseConfig | None
      frame_checks         gtvo.frontend.frame_checks.FrameCheckConfig
      motion_model         MotionModelConfig
      photometric          factors.params.PhotometricConfig
      loops                gtvo.loops.config.LoopClosureConfig (enabled, detector: LoopDetectorConfig
                                           (orb: OrbConfig, verification: VerificationConfig, ...))
      wheel                gtvo.config.wheel.WheelConfig (model, base_to_camera, nominal_baseline, ...)
      imu                  gtvo.config.imu.ImuConfig (enabled, topic, imu_in_camera, noise model, ...)
      refine               gtvo.refinement.config.RefineConfig (the whole-log refinement)

The photometric model (noise, Huber threshold, pattern, clipped range) is set once, in
``photometric``, and the tracker and the window are given that one object. The command line and
the library share these defaults: ``gtvo run`` and :func:`gtvo.run` run the same solvers, and a
solver name means both solvers in each (``OdometryConfig(solver="handrolled")``, ``--solver handrolled``).

The package: the tree (:mod:`gtvo.config.tree`); the configuration as plain data and files,
:func:`config_to_dict` / :func:`config_from_dict` (the inverse, checking every key, type and range),
:func:`config_to_yaml` and :func:`load_config` (a YAML or JSON file; ``gtvo run --config FILE``)
(:mod:`gtvo.config.files`); the documentation of every key, docs/configuration.md, written by
:func:`config_reference` (:mod:`gtvo.config.reference`).
"""

from gtvo.config.files import (MOVED_KEYS, ConfigKeyError, as_config, config_from_dict, config_to_dict, config_to_yaml,
                               load_config)
from gtvo.config.reference import config_reference, describe_key, field_docs
from gtvo.config.tree import (MIN_POINTS_PER_KEYFRAME, FlowPoseConfig,
                              FrontendConfig, KeyframeConfig, MotionModelConfig, MotionNoiseConfig, OdometryConfig,
                              PhotometricConfig, PointSelectionConfig, SolverConfig, StereoSearchConfig,
                              TrackingConfig, WindowConfig)
from gtvo.config.imu import ImuConfig
from gtvo.config.wheel import WheelConfig

__all__ = [
    "MIN_POINTS_PER_KEYFRAME", "MOVED_KEYS", "ConfigKeyError", "FlowPoseConfig",
    "FrontendConfig", "KeyframeConfig", "MotionModelConfig", "MotionNoiseConfig", "OdometryConfig", "PhotometricConfig",
    "PointSelectionConfig", "SolverConfig", "StereoSearchConfig", "TrackingConfig", "WheelConfig", "WindowConfig", "as_config",
    "config_from_dict", "config_reference", "config_to_dict", "config_to_yaml", "describe_key", "field_docs",
    "load_config",
]
