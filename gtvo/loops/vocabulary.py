"""A binary visual vocabulary (k-majority k-means over ORB descriptors) and TF-IDF bag-of-words
scores as in DBoW2 (Galvez-Lopez & Tardos, 2012).

* **Words**: ``n_words`` binary centres of the 256-bit ORB descriptors, found by k-majority
  clustering (k-means where the distance is Hamming and the centre update is the per-bit
  majority vote), seeded by k-means++. A descriptor's word is its nearest centre.
* **Document vector** of an image: ``v_w = tf_w * idf_w``, ``tf_w`` = count of its descriptors
  in word ``w`` (DBoW2 divides by the descriptor count, which the L1 normalisation cancels),
  ``idf_w = log(N / n_w)`` with ``N`` documents in the database and ``n_w`` of them containing
  ``w``. Vectors are L1-normalised.
* **Score** ``s(a, b) = 1 - 0.5 * |a - b|_1``, in [0, 1], which for L1-normalised non-negative
  vectors equals ``sum_w min(a_w, b_w)`` (computed that way).

Pure math: no I/O. Flat (one-level) vocabulary: with a few hundred words and up to thousands of
keyframes the brute-force scoring is a single vectorised pass, so DBoW2's tree is not needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.loops.features import ORB_BITS, signed_bits


@dataclass(frozen=True)
class BinaryVocabulary:
    """Binary visual words.

    Attributes:
        words: (K, 32) uint8 word centres (ORB-descriptor layout).
    """

    words: NDArray[np.uint8]

    def __post_init__(self) -> None:
        w = np.asarray(self.words)
        if w.ndim != 2 or w.shape[1] != ORB_BITS // 8 or w.shape[0] < 1 or w.dtype != np.uint8:
            raise InputError(f"vocabulary words must be a non-empty (K, 32) uint8 array, got {w.dtype} {w.shape}")

    @property
    def n_words(self) -> int:
        """Number of words K."""
        return int(self.words.shape[0])

    @classmethod
    def train(cls, descriptors: NDArray[np.uint8], n_words: int, iterations: int = 10,
              seed: int = 0) -> "BinaryVocabulary":
        """k-majority clustering of ORB descriptors (N, 32) into at most ``n_words`` words.

        Seeding is k-means++ on a subsample (each next seed drawn with probability proportional to the squared
        Hamming distance to the nearest chosen seed); then ``iterations`` rounds of assignment and
        per-bit majority update. Empty clusters keep their previous centre. Deterministic for a
        given ``seed``.
        """
        desc = np.asarray(descriptors)
        if desc.ndim != 2 or desc.shape[1] != ORB_BITS // 8 or desc.dtype != np.uint8:
            raise InputError(f"descriptors must be a (N, 32) uint8 array, got {desc.dtype} {desc.shape}")
        if desc.shape[0] == 0:
            raise InputError("cannot train a vocabulary from zero descriptors")
        if int(n_words) < 1:
            raise InputError(f"n_words must be >= 1, got {n_words}")
        rng = np.random.default_rng(seed)
        k = min(int(n_words), desc.shape[0])
        signs = signed_bits(desc)  # (N, 256) +-1
        n = signs.shape[0]
        # k-means++ seeding on a random subsample of at most max(4k, 2000) descriptors (the
        # sequential seeding is the slow part; its quality barely depends on the sample size).
        pool = signs[rng.choice(n, min(n, max(4 * k, 2000)), replace=False)]
        m = pool.shape[0]
        centres = np.empty((k, ORB_BITS), dtype=np.float32)
        centres[0] = pool[rng.integers(m)]
        nearest = 0.5 * (ORB_BITS - pool @ centres[0])
        for c in range(1, k):
            weights = nearest.astype(np.float64) ** 2
            cdf = np.cumsum(weights)
            pick = rng.integers(m) if cdf[-1] <= 0 else int(np.searchsorted(cdf, rng.random() * cdf[-1], side="right"))
            centres[c] = pool[min(pick, m - 1)]
            nearest = np.minimum(nearest, 0.5 * (ORB_BITS - pool @ centres[c]))
        bits = (signs > 0).astype(np.float32)
        for _ in range(int(iterations)):
            assign = np.argmax(signs @ centres.T, axis=1)  # max dot product = min Hamming
            counts = np.bincount(assign, minlength=k).astype(np.float32)
            onehot = sparse.csr_matrix((np.ones(n, dtype=np.float32), (assign, np.arange(n))), shape=(k, n))
            ones = np.asarray(onehot @ bits)  # (k, 256) count of set bits per cluster
            new = np.where(2.0 * ones > counts[:, None], 1.0, -1.0).astype(np.float32)
            keep_old = counts == 0
            new[keep_old] = centres[keep_old]
            if np.array_equal(new, centres):
                break
            centres = new
        words = np.packbits(centres > 0, axis=1).astype(np.uint8)
        return cls(words)

    def quantise(self, descriptors: NDArray[np.uint8]) -> NDArray[np.int64]:
        """The word id (N,) of each descriptor (nearest word in Hamming distance)."""
        desc = np.asarray(descriptors, dtype=np.uint8)
        if desc.shape[0] == 0:
            return np.zeros(0, dtype=np.int64)
        return np.argmax(signed_bits(desc) @ signed_bits(self.words).T, axis=1).astype(np.int64)

    def term_counts(self, descriptors: NDArray[np.uint8]) -> NDArray[np.float64]:
        """Histogram (K,) of the descriptors' words (the raw term frequencies of one image)."""
        return np.bincount(self.quantise(descriptors), minlength=self.n_words).astype(np.float64)


def idf_weights(term_counts: NDArray[np.float64]) -> NDArray[np.float64]:
    """``idf_w = log(N / n_w)`` over a database of N documents (rows of ``term_counts``, (N, K));
    words in no document get weight 0."""
    tc = np.asarray(term_counts, dtype=np.float64)
    n_docs = tc.shape[0]
    df = np.count_nonzero(tc > 0, axis=0)
    return np.where(df > 0, np.log(np.maximum(n_docs, 1) / np.maximum(df, 1)), 0.0)


def tfidf_vectors(term_counts: NDArray[np.float64], idf: NDArray[np.float64]) -> NDArray[np.float64]:
    """L1-normalised TF-IDF vectors (rows) from term counts (N, K) and idf (K,); all-zero rows
    stay zero."""
    v = np.atleast_2d(np.asarray(term_counts, dtype=np.float64)) * idf[None, :]
    norm = v.sum(axis=1, keepdims=True)
    return np.divide(v, norm, out=np.zeros_like(v), where=norm > 0)


def l1_scores(query: NDArray[np.float64], database: NDArray[np.float64]) -> NDArray[np.float64]:
    """DBoW2's L1 score ``1 - 0.5 |q - d|_1 = sum min(q, d)`` of one L1-normalised vector (K,)
    against each row of ``database`` (M, K); result (M,) in [0, 1]."""
    return np.minimum(np.asarray(database)[:, :], np.asarray(query)[None, :]).sum(axis=1)
