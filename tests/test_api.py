import subprocess
import sys

import pytest

import gtvo


def test_top_level_api_names_resolve():
    for name in gtvo.__all__:
        assert getattr(gtvo, name) is not None
    from gtvo.odometry import VisualOdometry

    assert gtvo.VisualOdometry is VisualOdometry


def test_import_gtvo_is_cheap():
    code = "import sys, gtvo; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.slow
def test_api_run_on_synthetic(tmp_path):
    from gtvo.datasets.synthetic import make_synthetic_sequence

    rep = gtvo.run(make_synthetic_sequence(n_frames=5), out=tmp_path, config={"frontend": {"points_per_keyframe": 400}})
    assert rep["frames"] == 5 and (tmp_path / "trajectory.tum").is_file()
