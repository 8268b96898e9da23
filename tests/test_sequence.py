"""The Sequence container (gtvo/sequence.py): subsampling a log to a lower frame rate."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.synthetic import make_synthetic_sequence


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
