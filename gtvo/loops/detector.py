"""The keyframe database of loop closing: bag-of-words retrieval and geometric verification.

>>> det = LoopDetector(stereo_camera)                                   # doctest: +SKIP
>>> det.add_keyframe(k, left, right, T_world_cam=T)                      # doctest: +SKIP
>>> for loop in det.query(k):                                            # doctest: +SKIP
...     graph.add(loop.between_factor())

Retrieval (docs/loop_closure.md): every keyframe's ORB descriptors are quantised into the words
of a :class:`BinaryVocabulary` trained online on the database itself (retrained whenever the
database has doubled since the last training, so the cost stays amortised O(1) per keyframe, or
fixed when one is given). A query ``i`` scores every keyframe inserted more than
``temporal_window`` keyframes before it with DBoW2's L1 score of TF-IDF vectors and divides by the
reference score ``s(i, best of its reference_neighbours preceding keyframes)`` (DBoW2's normalised
score ``eta``). Candidates with ``eta >= min_normalised_score`` are grouped into islands of
consecutive keyframes; the best member of each of the ``max_candidates`` best islands is verified
by ORB matching and PnP RANSAC against its stereo/depth 3-D points.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import cv2
import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from gtvo.core import keys
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.errors import InputError, show
from gtvo.core.image import to_uint8
from gtvo.config.sections.loops import LoopDetectorConfig, OrbConfig, VerificationConfig
from gtvo.loops.features import (KeypointPoints, OrbFeatures, depth_image_points, extract_orb,
                                 stereo_points)
from gtvo.loops.verification import match_descriptors, verify_pnp
from gtvo.loops.vocabulary import BinaryVocabulary, idf_weights, l1_scores, tfidf_vectors
from gtvo.datasets.sequence import Sequence

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LoopCandidate:
    """A verified loop between query keyframe ``i`` and keyframe ``j`` (earlier, from :meth:`LoopDetector.query`).

    Attributes:
        i: the query keyframe's index (as given to :meth:`LoopDetector.add_keyframe`).
        j: the matched keyframe's index.
        T_i_j: 4x4 pose of ``j`` in ``i``'s camera frame, ``T_world_i^-1 T_world_j``: the
            measurement of ``BetweenFactorPose3(x_i, x_j, T_i_j)``.
        inliers: PnP inlier count.
        score: DBoW2's normalised score ``eta = s(i, j) / s_ref(i)`` (docs/loop_closure.md).
        information: 6x6 information of ``T_i_j``, GTSAM Pose3 tangent [rot, trans], right
            perturbation (``T_i_j * Exp(xi)``), with the covariance floor of
            :class:`VerificationConfig`.
        similarity: raw L1 bag-of-words score ``s(i, j)`` in [0, 1].
        n_matches: ORB matches tried by PnP.
        rmse_px: inlier reprojection RMSE after refinement (pixels).
    """

    i: int
    j: int
    T_i_j: FloatArray
    inliers: int
    score: float
    information: FloatArray
    similarity: float = 0.0
    n_matches: int = 0
    rmse_px: float = 0.0

    def between_factor(self, symbol_char: str = keys.POSE) -> gtsam.BetweenFactorPose3:
        """``BetweenFactorPose3(symbol(c, i), symbol(c, j), T_i_j)`` with a Gaussian noise model of
        :attr:`information` (wrap it in a robust kernel or use GNC in the pose graph)."""
        noise = gtsam.noiseModel.Gaussian.Information(self.information)
        return gtsam.BetweenFactorPose3(gtsam.symbol(symbol_char, self.i), gtsam.symbol(symbol_char, self.j),
                                        gtsam.Pose3(self.T_i_j), noise)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form: indices, scores, ``T_i_j`` (4x4 rows) and ``information`` (6x6 rows)."""
        return {"i": self.i, "j": self.j, "inliers": self.inliers, "n_matches": self.n_matches,
                "score": self.score, "similarity": self.similarity, "rmse_px": self.rmse_px,
                "T_i_j": np.asarray(self.T_i_j).tolist(), "information": np.asarray(self.information).tolist()}


@dataclass
class Keyframe:
    """One database entry.

    Attributes:
        index: the caller's keyframe index.
        rank: insertion order (0, 1, ...).
        features: ORB keypoints of the left image.
        points: 3-D points behind the keypoints (camera frame) with covariances.
        T_world_cam: the caller's pose estimate when inserted (None when not given); not used
            by retrieval or verification (drift-free), kept for the pose-graph builder.
        term_counts: (K,) word histogram under the current vocabulary (None before training).
    """

    index: int
    rank: int
    features: OrbFeatures
    points: KeypointPoints
    T_world_cam: FloatArray | None
    term_counts: FloatArray | None = None


def _check_pose(T: ArrayLike) -> FloatArray:
    M = np.asarray(T, dtype=np.float64)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise InputError(f"T_world_cam must be a finite 4x4 matrix, got shape {M.shape}")
    if not np.allclose(M[3], [0, 0, 0, 1]) or not np.allclose(M[:3, :3].T @ M[:3, :3], np.eye(3), atol=1e-6):
        raise InputError("T_world_cam is not a rigid transform (bottom row or rotation invalid)")
    return M


class LoopDetector:
    """Keyframe database for place recognition and verified loop candidates.

    Args:
        camera: the rectified :class:`StereoCamera` (keyframes then pass a right image) or a
            :class:`PinholeCamera` (keyframes then pass a metric depth image).
        config: thresholds; see :class:`LoopDetectorConfig`.
        vocabulary: a fixed vocabulary (e.g. trained offline); None trains one online.
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: LoopDetectorConfig | None = None,
                 vocabulary: BinaryVocabulary | None = None):
        if not isinstance(camera, (StereoCamera, PinholeCamera)):
            raise InputError(f"camera must be a StereoCamera or PinholeCamera, got {type(camera).__name__}")
        self.camera = camera
        self.config = config if config is not None else LoopDetectorConfig()
        self._vocabulary = vocabulary
        self._fixed_vocabulary = vocabulary is not None
        self._trained_at = 0
        self._keyframes: list[Keyframe] = []
        self._by_index: dict[int, Keyframe] = {}
        self._orb: cv2.ORB = self.config.orb.create()

    @property
    def pinhole(self) -> PinholeCamera:
        """The left pinhole camera."""
        return self.camera.left if isinstance(self.camera, StereoCamera) else self.camera

    @property
    def vocabulary(self) -> BinaryVocabulary | None:
        """The current vocabulary (None until trained)."""
        return self._vocabulary

    def __len__(self) -> int:
        return len(self._keyframes)

    @property
    def indices(self) -> list[int]:
        """The frame indices of the keyframes in the database, in the order they were added."""
        return [kf.index for kf in self._keyframes]

    def keyframe(self, index: int) -> Keyframe:
        """The database entry of keyframe ``index``."""
        try:
            return self._by_index[int(index)]
        except KeyError:
            raise InputError(f"keyframe {index} is not in the loop-detection database") from None

    def add_keyframe(self, index: int, left: NDArray, right: NDArray | None = None, *, depth: NDArray | None = None,
                     T_world_cam: ArrayLike | None = None) -> Keyframe:
        """Insert keyframe ``index``: ORB features of ``left`` and their 3-D points, from a rectified
        ``right`` image (stereo camera) or a metric ``depth`` image (metres, 0 = unknown).

        Raises:
            InputError: duplicate index, wrong image size, NaN, both/neither of right and depth,
                or an invalid pose.
        """
        index = int(index)
        if index in self._by_index:
            raise InputError(f"keyframe {index} was already added to the loop-detection database")
        cam = self.pinhole
        left_u8 = to_uint8(left, "left image")
        if left_u8.shape != (cam.height, cam.width):
            raise InputError(f"left image is {left_u8.shape[1]}x{left_u8.shape[0]}, "
                             f"the camera expects {cam.width}x{cam.height}")
        if (right is None) == (depth is None):
            raise InputError("add_keyframe needs exactly one of a right image or a depth image")
        pose = None if T_world_cam is None else _check_pose(T_world_cam)
        feats = extract_orb(left_u8, self.config.orb, self._orb)
        vp = self.config.verification
        if right is not None:
            if not isinstance(self.camera, StereoCamera):
                raise InputError("a right image needs the detector to be built with a StereoCamera")
            pts = stereo_points(feats, left_u8, right, self.camera, self.config.orb,
                                max_hamming=self.config.stereo_max_hamming, pixel_sigma_px=vp.pixel_sigma_px,
                                disparity_sigma_px=self.config.disparity_sigma_px, detector=self._orb)
        else:
            dep = np.asarray(depth)
            if dep.dtype.kind == "f" and np.any(np.isnan(dep)):
                raise InputError("depth image contains NaN (use 0 for unknown depth)")
            pts = depth_image_points(feats, dep, cam, self.config.orb, pixel_sigma_px=vp.pixel_sigma_px,
                                     depth_noise_per_m=self.config.depth_noise_per_m)
        kf = Keyframe(index, len(self._keyframes), feats, pts, pose)
        if self._vocabulary is not None:
            kf.term_counts = self._vocabulary.term_counts(feats.descriptors)
        self._keyframes.append(kf)
        self._by_index[index] = kf
        return kf

    # ------------------------------------------------------------------ retrieval
    def _update_vocabulary(self) -> None:
        n = len(self._keyframes)
        if self._fixed_vocabulary:
            return
        if n < self.config.min_training_keyframes:
            return
        if self._vocabulary is not None and n < 2 * self._trained_at:
            return
        desc = np.concatenate([kf.features.descriptors for kf in self._keyframes], axis=0)
        if desc.shape[0] == 0:
            return
        rng = np.random.default_rng(self.config.seed)
        if desc.shape[0] > self.config.max_training_descriptors:
            desc = desc[rng.choice(desc.shape[0], self.config.max_training_descriptors, replace=False)]
        self._vocabulary = BinaryVocabulary.train(desc, self.config.n_words, self.config.vocabulary_iterations,
                                                  seed=self.config.seed)
        self._trained_at = n
        for kf in self._keyframes:
            kf.term_counts = self._vocabulary.term_counts(kf.features.descriptors)

    def similarities(self, index: int) -> tuple[FloatArray, float]:
        """Raw L1 scores ``s(i, k)`` (by insertion rank, over the keyframes inserted up to ``i``) and
        the reference score of query ``i`` (the floor when it has no preceding keyframe).

        Trains or retrains the online vocabulary first when it is due (see the module docstring);
        before the first training all scores are 0."""
        kf = self.keyframe(index)
        self._update_vocabulary()
        if self._vocabulary is None:
            return np.zeros(kf.rank + 1), float(self.config.min_reference_score)
        counts = np.stack([k.term_counts for k in self._keyframes[:kf.rank + 1]])
        vectors = tfidf_vectors(counts, idf_weights(counts))
        scores = l1_scores(vectors[kf.rank], vectors)
        lo = max(0, kf.rank - self.config.reference_neighbours)
        neighbour = scores[lo:kf.rank]
        reference = max(float(neighbour.max()) if neighbour.size else 0.0, float(self.config.min_reference_score))
        return scores, reference

    def query(self, index: int) -> list[LoopCandidate]:
        """Verified loops of keyframe ``index`` against keyframes inserted before it, excluding the
        last ``temporal_window`` of them; best normalised score first (empty list when none)."""
        kf = self.keyframe(index)
        cfg = self.config
        last = kf.rank - cfg.temporal_window  # candidates have rank < last
        if last <= 0:
            return []
        scores, reference = self.similarities(index)
        eta = scores[:last] / reference
        ranks = np.flatnonzero(eta >= cfg.min_normalised_score)
        if ranks.size == 0:
            return []
        # Islands of consecutive ranks (DBoW2): score = sum of eta, representative = best member.
        breaks = np.flatnonzero(np.diff(ranks) > cfg.island_gap) + 1
        islands = np.split(ranks, breaks)
        island_scores = np.array([eta[isl].sum() for isl in islands])
        out: list[LoopCandidate] = []
        for k in np.argsort(-island_scores, kind="stable")[:cfg.max_candidates]:
            isl = islands[k]
            rank_j = int(isl[np.argmax(eta[isl])])
            loop = self._verify(kf, self._keyframes[rank_j], float(eta[rank_j]), float(scores[rank_j]))
            if loop is not None:
                out.append(loop)
        out.sort(key=lambda c: -c.score)
        return out

    # ------------------------------------------------------------------ verification
    def verify(self, i: int, j: int) -> LoopCandidate | None:
        """Geometric verification of query keyframe ``i`` against keyframe ``j`` regardless of the
        retrieval (no temporal window, no score threshold): ``T_i_j`` or None when rejected.
        The scores are those :meth:`query` computes (idf over the database up to the later of the two)."""
        kf_i, kf_j = self.keyframe(i), self.keyframe(j)
        if kf_i.index == kf_j.index:
            raise InputError(f"cannot verify keyframe {i} against itself")
        scores_i, reference = self.similarities(kf_i.index)
        if kf_j.rank < kf_i.rank:
            s = float(scores_i[kf_j.rank])
        else:  # the L1 score is symmetric; idf over the database up to j
            s = float(self.similarities(kf_j.index)[0][kf_i.rank])
        return self._verify(kf_i, kf_j, s / reference, s)

    def _verify(self, kf_i: Keyframe, kf_j: Keyframe, score: float, similarity: float) -> LoopCandidate | None:
        vp = self.config.verification
        has_3d = np.flatnonzero(kf_j.points.valid)
        if has_3d.size < vp.min_inliers or len(kf_i.features) < vp.min_inliers:
            return None
        qi, cj = match_descriptors(kf_i.features.descriptors, kf_j.features.descriptors[has_3d], vp.ratio,
                                   vp.max_hamming)
        cj = has_3d[cj]
        sigmas = vp.pixel_sigma_px * self.config.orb.scale_factor ** kf_i.features.octave[qi]
        result = verify_pnp(kf_j.points.points[cj], kf_j.points.covariances[cj], kf_i.features.uv[qi], sigmas,
                            self.pinhole, vp)
        if result is None:
            return None
        return LoopCandidate(kf_i.index, kf_j.index, result.T_i_j, int(result.inliers.size), score,
                             result.information, similarity, result.n_matches, result.rmse_px)


def detect_loops(sequence: Sequence, frames: Iterable[int] | None = None, config: LoopDetectorConfig | None = None,
                 progress: bool = False, strict: bool = False,
                 warn: Callable[[str], None] | None = None) -> tuple[LoopDetector, list[LoopCandidate]]:
    """Run place recognition over a sequence: every frame in ``frames`` (all when None) is added as a
    keyframe (right image or depth image by the sequence's kind) and queried right after.

    With ``strict=False`` a frame whose images cannot be read (missing, corrupt, wrong size, NaN)
    is skipped: ``warn`` (default: a line on stderr) names it and it is left out of the database,
    as ``gtvo run`` does; ``strict=True`` raises the :class:`InputError` instead. The frames that
    made it in are ``detector.indices``.

    Returns the detector (its database) and all verified loops in query order.
    """
    det = LoopDetector(sequence.camera, config)
    indices = list(range(len(sequence))) if frames is None else [int(k) for k in frames]
    warn = warn or (lambda msg: print(f"warning: {msg}", file=sys.stderr))
    loops: list[LoopCandidate] = []
    for k in tqdm(indices, desc=f"loops {sequence.name}", unit="kf", disable=not progress):
        if not 0 <= k < len(sequence):
            raise InputError(f"frame {k} out of range 0..{len(sequence) - 1}")
        try:
            images = ((sequence.left(k), sequence.right(k), None) if sequence.kind == "stereo"
                      else (sequence.left(k), None, sequence.depth(k)))
        except InputError as exc:
            if strict:
                raise
            warn(f"skipping frame {k}: {exc}")
            continue
        det.add_keyframe(k, images[0], images[1], depth=images[2])
        loops += det.query(k)
    return det, loops
