"""The configuration tree of a VO run: :class:`OdometryConfig` and the settings it nests.

One place for every setting of a run (KISS-ICP's single config), one frozen dataclass per
component, each field's default and allowed range declared once beside it
(:func:`gtvo.core.settings.setting`)::

    OdometryConfig
      mode                 "window" | "track"
      solver               SolverConfig (tracker, window)
      frontend             FrontendConfig (points_per_keyframe, points: PointSelectionConfig,
                                           stereo: StereoSearchConfig, depth_sigma_model)
      keyframes            KeyframeConfig
      tracking             TrackingConfig
      window               WindowConfig
      flow_fallback        FlowPoseConfig | None
      frame_checks         FrameCheckConfig
      motion_model         MotionModelConfig (model, accept_rms_factor, kalman_noise: MotionNoiseConfig, ...)
      photometric          factors.params.PhotometricConfig
      loops                LoopClosureConfig (enabled, detector: LoopDetectorConfig
                                           (orb: OrbConfig, verification: VerificationConfig, ...))
      wheel                WheelConfig (model, base_to_camera, nominal_baseline, ...)
      imu                  ImuConfig (enabled, topic, imu_in_camera, noise model, ...)
      refine               RefineConfig (the whole-log refinement)

Each section lives in its own module of :mod:`gtvo.config.sections`, which imports only the
settings core (:mod:`gtvo.core.settings`) and :mod:`factors.params`: the settings are a leaf, and
``import gtvo.config`` loads no reader, front end, window, loop closing or refinement. The
components import their section from there.

The photometric model (noise, Huber threshold, pattern, clipped range) is set once, in
``photometric``, and the tracker and the window are given that one object. The command line and
the library share these defaults: ``gtvo run`` and :func:`gtvo.run` run the same solvers, and a
solver name means both solvers in each (``OdometryConfig(solver="handrolled")``, ``--solver handrolled``).

The package: the tree (:mod:`gtvo.config.tree`) and its sections (:mod:`gtvo.config.sections`); the configuration as plain data and files,
:func:`config_to_dict` / :func:`config_from_dict` (the inverse, checking every key, type and range),
:func:`config_to_yaml` and :func:`load_config` (a YAML or JSON file; ``gtvo run --config FILE``)
(:mod:`gtvo.config.files`); the documentation of every key, docs/configuration.md, written by
:func:`config_reference` (:mod:`gtvo.config.reference`).
"""

from gtvo.config.files import (MOVED_KEYS, ConfigKeyError, as_config, config_from_dict, config_to_dict, config_to_yaml,
                               load_config)
from gtvo.config.reference import config_reference, describe_key, field_docs
from gtvo.config.tree import (MIN_POINTS_PER_KEYFRAME, FlowPoseConfig, FrameCheckConfig, FrontendConfig,
                              ImuConfig, KeyframeConfig, LoopClosureConfig, MotionModelConfig, MotionNoiseConfig, OdometryConfig,
                              PhotometricConfig, PointSelectionConfig, RefineConfig, SolverConfig, StereoSearchConfig,
                              TrackingConfig, WheelConfig, WindowConfig)

__all__ = [
    "MIN_POINTS_PER_KEYFRAME", "MOVED_KEYS", "ConfigKeyError", "FlowPoseConfig", "FrameCheckConfig",
    "FrontendConfig", "ImuConfig", "KeyframeConfig", "LoopClosureConfig", "MotionModelConfig", "MotionNoiseConfig", "OdometryConfig",
    "PhotometricConfig", "PointSelectionConfig", "RefineConfig", "SolverConfig", "StereoSearchConfig", "TrackingConfig",
    "WheelConfig", "WindowConfig", "as_config",
    "config_from_dict", "config_reference", "config_to_dict", "config_to_yaml", "describe_key", "field_docs",
    "load_config",
]
