"""Loop closing, place-recognition part: ORB features, an online binary bag-of-words vocabulary
(DBoW2-style TF-IDF and normalised scores), a keyframe database with temporal exclusion and
geometric verification by PnP RANSAC on stereo/depth points. Math and conventions:
``docs/loop_closure.md``. The pose graph that consumes :class:`LoopCandidate` lives elsewhere.
"""

from gtvo.config.sections.loops import LoopClosureConfig, LoopDetectorConfig, OrbConfig, VerificationConfig
from gtvo.loops.detector import Keyframe, LoopCandidate, LoopDetector, detect_loops
from gtvo.loops.features import (KeypointPoints, OrbFeatures, depth_image_points, extract_orb,
                                 hamming_distances, stereo_points)
from gtvo.loops.verification import (PnPResult, match_descriptors, pose_information,
                                     reprojection_jacobians, verify_pnp)
from gtvo.loops.vocabulary import BinaryVocabulary, idf_weights, l1_scores, tfidf_vectors

__all__ = ["BinaryVocabulary", "KeypointPoints", "Keyframe", "LoopCandidate", "LoopClosureConfig", "LoopDetector",
           "LoopDetectorConfig",
           "OrbFeatures", "OrbConfig", "PnPResult", "VerificationConfig", "depth_image_points", "detect_loops", "extract_orb",
           "hamming_distances", "idf_weights", "l1_scores", "match_descriptors", "pose_information",
           "reprojection_jacobians", "stereo_points", "tfidf_vectors", "verify_pnp"]
