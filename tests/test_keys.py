"""The GTSAM keys of the VO problem (gtvo.core.keys): the characters of docs/conventions.md, one per
kind of variable, so graphs built by different modules agree on them."""

from __future__ import annotations

import gtsam

from gtvo.core import keys


def test_keys_follow_the_conventions_table():
    for fn, char in [(keys.pose_key, "x"), (keys.inverse_depth_key, "d"), (keys.affine_key, "a"),
                     (keys.right_affine_key, "r"), (keys.motion_state_key, "v"), (keys.calibration_key, "c")]:
        s = gtsam.Symbol(fn(12))
        assert (chr(s.chr()), s.index()) == (char, 12)
    assert keys.calibration_key() == gtsam.symbol("c", 0)


def test_keys_of_different_kinds_never_collide():
    makers = [keys.pose_key, keys.inverse_depth_key, keys.affine_key, keys.right_affine_key, keys.motion_state_key,
              keys.calibration_key]
    all_keys = {fn(i) for fn in makers for i in range(50)}
    assert len(all_keys) == len(makers) * 50
    assert keys.is_pose_key(keys.pose_key(7)) and not keys.is_pose_key(keys.affine_key(7))
