"""The Sequence container (gtvo/datasets/sequence.py): subsampling a log to a lower frame rate."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.datasets.synthetic import SyntheticSequence, make_synthetic_sequence


@pytest.mark.slow
def test_subsampled_keeps_every_step_th_frame():
    seq = make_synthetic_sequence(n_frames=7)
    sub = seq.subsampled(3)
    assert len(sub) == 3
    np.testing.assert_array_equal(sub.timestamps, seq.timestamps[[0, 3, 6]])
    np.testing.assert_array_equal(sub.gt_poses, seq.gt_poses[[0, 3, 6]])
    assert sub.frame_names == [seq.frame_names[i] for i in (0, 3, 6)]
    assert sub.left(1).tobytes() == seq.left(3).tobytes()
    assert sub.right(2).tobytes() == seq.right(6).tobytes()
    assert sub.frame(2).index == 2 and sub.frame(2).timestamp == seq.timestamps[6]
    assert seq.subsampled(1) is seq
    with pytest.raises(InputError, match="step must be >= 1"):
        seq.subsampled(0)


def test_sub_sequences_of_a_synthetic_sequence_keep_its_exact_depth():
    seq = make_synthetic_sequence(n_frames=7)
    sub = seq.subsampled(3)  # frames 0, 3, 6
    assert isinstance(sub, SyntheticSequence)
    np.testing.assert_array_equal(sub.true_depth(1), seq.true_depth(3))
    np.testing.assert_array_equal(sub.face_ids(2, "right"), seq.face_ids(6, "right"))
    np.testing.assert_array_equal(sub.affine_left, seq.affine_left[[0, 3, 6]])
    nested = sub.truncated(2).subsampled(1)
    assert isinstance(nested, SyntheticSequence) and len(nested) == 2
    np.testing.assert_array_equal(nested.true_depth(1), seq.true_depth(3))
    assert sub.subsampled(2).left(1).tobytes() == seq.left(6).tobytes()  # frames 0, 6 of the original
    np.testing.assert_array_equal(sub.subsampled(2).true_depth(1), seq.true_depth(6))
    with pytest.raises(IndexError):
        sub.true_depth(3)
