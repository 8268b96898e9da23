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


def test_readme_library_snippet_gives_the_last_keyframes_covariance(shared_data):
    """The README's library snippet, run as written on the first 6 frames of KITTI_sequence_1
    (keyframes at every frame, the window optimised after every second one): its
    ``vo.covariance(vo.keyframes[-1])`` is the 6x6 covariance it promises."""
    import re
    from pathlib import Path

    import pytest

    root = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1"
    if not root.is_dir():
        pytest.skip(f"{root} not found")
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = next(b for b in re.findall(r"```python\n(.*?)```", readme, re.S) if "vo.covariance(" in b)
    lines = [ln for ln in block.splitlines() if "log.bag" not in ln]  # (no bag here)
    code = "\n".join(lines).replace('open_sequence("KITTI_sequence_1")', f"open_sequence({str(root)!r}, max_frames=6)")
    names: dict = {}
    exec(compile(code, "README.md", "exec"), names)  # noqa: S102 - the README's own code
    assert len(names["vo"].keyframes) == 6
    assert names["P"] is not None and names["P"].shape == (6, 6)
