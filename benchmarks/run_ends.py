"""The ends of a ``gtvo run``: CPU before the first frame, after the last, and the peak memory.

Usage::

    python benchmarks/run_ends.py --runs 3                                   # this checkout alone
    python benchmarks/run_ends.py --ref /path/to/main --runs 3               # against another checkout
    python benchmarks/run_ends.py --ref /path/to/main -- --max-frames 20     # more `gtvo run` arguments

Runs ``python -m gtvo run KITTI_sequence_1 --no-progress`` (extra arguments after ``--``) from this
checkout and from ``--ref``, alternately, each in a fresh process whose clocks are read at three
points without changing what the run does: the CPU time of the process (user + system, all threads,
``time.process_time``) when ``VisualOdometry.process`` is first entered (*before the first frame*:
the interpreter, the imports, the readers, the output checks), when its last call returns, and at
the process's end (``os.wait4``'s user + system time: the teardown included). *After the last frame*
is the difference of the last two: the final window optimisation, the covariances, the evaluation, the
plots, the map and the report, the exit; *exit* is its part after the last exit handler (the operating
system freeing the process's memory, in its system time). *First frame*: the first call's CPU, of it
*first-frame kernels* the loading of compiled kernels (numba's first load also sets up its compiler's
tables: about half of it). *Kernel loads* is the CPU spent loading numba's compiled
kernels from the disk cache (wherever in the run they load). Peak RSS is ``wait4``'s ``ru_maxrss``.

*Library floor*, measured after each round: a bare interpreter importing numpy, cv2, numba and gtsam
(*libraries*), then scipy.linalg (which numba imports when it loads its first compiled kernel), then
numba's first load of one cached one-line kernel: what no run can spend less than before its first
frame's result.

Without ``--ref`` only this checkout runs. CPU time, not wall time: the machine may be shared.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("GTVO_SHARED_DATA", REPO.parent / "shared" / "data"))
KITTI = DATA / "kitti_stereo_sample" / "KITTI_sequence_1"

# The child: installs a post-import hook on gtvo.odometry.visual_odometry (so that nothing is imported
# earlier than the run itself imports it) and numba's cache loader, then runs the CLI's entry point.
_CHILD = r"""
import importlib.abc, importlib.machinery, os, sys, time
_marks = {"first": None, "first_done": None, "last": None, "kernel_load": 0.0, "kernel_load_first": None, "exit": None}
_out = sys.argv.pop(1)

def _write():
    _marks["exit"] = time.process_time()
    with open(_out, "w") as f:
        f.write(" ".join(repr(_marks[k]) for k in ("first", "first_done", "last", "kernel_load", "kernel_load_first", "exit")))

def _patch_vo(module):
    cls = module.VisualOdometry
    process = cls.process
    def timed(self, frame):
        if _marks["first"] is None:
            _marks["first"] = time.process_time()
        try:
            return process(self, frame)
        finally:
            _marks["last"] = time.process_time()
            if _marks["first_done"] is None:
                _marks["first_done"], _marks["kernel_load_first"] = _marks["last"], _marks["kernel_load"]
    cls.process = timed

def _patch_numba(module):
    cache = module.Cache
    load = cache.load_overload
    def timed(self, *a, **k):
        t = time.process_time()
        try:
            return load(self, *a, **k)
        finally:
            _marks["kernel_load"] += time.process_time() - t
    cache.load_overload = timed

_HOOKS = {"gtvo.odometry.visual_odometry": _patch_vo, "numba.core.caching": _patch_numba}

class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name not in _HOOKS:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None:
            return None
        exec_module = spec.loader.exec_module
        def run(module, _exec=exec_module, _hook=_HOOKS[name]):
            _exec(module)
            _hook(module)
        spec.loader.exec_module = run
        return spec

sys.meta_path.insert(0, _Finder())
import atexit
atexit.register(_write)
sys.argv[0] = "gtvo"
from gtvo.cli import entry_point
entry_point()
"""


def child_env(tree: Path, pyc: bool) -> dict[str, str]:
    """The run's environment: ``tree`` on the path; with ``pyc``, Python's compiled modules cached as an
    installed package has them (outside the checkout: ``PYTHONPYCACHEPREFIX``), else every module is
    compiled from its source in every run (``PYTHONDONTWRITEBYTECODE`` without cached files)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "MPLBACKEND": "Agg"}
    if pyc:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(Path(tempfile.gettempdir()) / "gtvo_ends_pyc" / str(tree).strip("/").replace("/", "+"))
    return env


def run_once(tree: Path, args: list[str], out: Path, pyc: bool = True) -> dict:
    """One ``gtvo run`` from ``tree``: its marks, total CPU and peak RSS."""
    marks = out.with_suffix(".marks")
    env = child_env(tree, pyc)
    cmd = [sys.executable, "-c", _CHILD, str(marks), "run", str(KITTI), "--out", str(out), "--no-progress", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, cwd=tree, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode() if proc.stderr else ""
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{tree}: gtvo run failed ({proc.returncode}): {err.strip()[-500:]}")
    first, first_done, last, kernel_load, kernel_load_first, at_exit = (float(x) for x in marks.read_text().split())
    total = usage.ru_utime + usage.ru_stime
    return {"before_first": first, "first_frame": first_done - first, "first_frame_kernels": kernel_load_first,
            "after_last": total - last, "exit": total - at_exit, "total": total, "wall": wall, "kernel_load": kernel_load,
            "rss_mib": usage.ru_maxrss / 1024}


_FLOOR_KERNEL = "import numba\n@numba.njit(cache=True)\ndef one(x):\n    return x + 1\n"
_FLOOR_CHILD = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
import numpy, cv2, numba, gtsam
libs = time.process_time()
import scipy.linalg
scipy_done = time.process_time()
import floor_kernel
t = time.process_time()
floor_kernel.one(1)
print(libs, scipy_done - libs, time.process_time() - t)
"""


def library_floor(folder: Path) -> dict:
    """What no ``gtvo run`` can spend less than before its first frame's result, in a fresh interpreter:
    the interpreter with numpy, cv2, numba and gtsam imported (everything gtvo runs on; gtsam's
    poses are the front end's), then scipy.linalg (numba imports it when it loads its first compiled
    kernel: ``numba.np.arraymath``), then numba's first load of one cached one-line kernel (its
    compiler's set-up)."""
    (folder / "floor_kernel.py").write_text(_FLOOR_KERNEL)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(folder / "pyc")
    cmd = [sys.executable, "-c", _FLOOR_CHILD, str(folder)]
    subprocess.run(cmd, env=env, check=True, capture_output=True)  # caches the kernel and the modules
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout.split()
    libs, scipy_linalg, kernel = (float(x) for x in out)
    return {"libraries": libs, "scipy_linalg": scipy_linalg, "first_kernel_load": kernel}


def summary(rows: list[dict], key: str) -> str:
    values = [r[key] for r in rows]
    return f"{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f})"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="runs of each checkout (default 3)")
    ap.add_argument("--ref", type=Path, default=None, help="a second checkout, run alternately (e.g. main)")
    ap.add_argument("--tree", type=Path, default=REPO, help="the checkout to measure (default this one)")
    ap.add_argument("--no-pyc", action="store_true",
                    help="no cached compiled modules: every module compiled from source (PYTHONDONTWRITEBYTECODE)")
    ap.add_argument("extra", nargs="*", help="more `gtvo run` arguments (after --)")
    a = ap.parse_args()
    trees = {"this": a.tree} | ({"ref": a.ref} if a.ref is not None else {})
    rows: dict[str, list[dict]] = {k: [] for k in trees}
    floors: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="gtvo_ends_") as tmp:
        for name, tree in trees.items():  # warm-up, not counted: compiled modules and kernels cached
            run_once(tree, ["--max-frames", "3"], Path(tmp) / f"{name}_warm", not a.no_pyc)
        for i in range(a.runs):
            for name, tree in trees.items():
                rows[name].append(run_once(tree, a.extra, Path(tmp) / f"{name}{i}", not a.no_pyc))
            floors.append(library_floor(Path(tmp)))
    print(f"load {os.getloadavg()[0]:.1f}; CPU s (median, range) of {a.runs} runs each")
    keys = ("before_first", "first_frame", "first_frame_kernels", "after_last", "exit", "total", "kernel_load",
            "rss_mib", "wall")
    print("| checkout | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for name, tree in trees.items():
        print(f"| {name} ({tree}) | " + " | ".join(summary(rows[name], k) for k in keys) + " |")
    print("library floor, a bare interpreter (median, range): " + ", ".join(
        f"{k} {summary(floors, k)}" for k in ("libraries", "scipy_linalg", "first_kernel_load")))
    if a.ref is not None:
        print("ratios this / ref (medians): " + ", ".join(
            f"{k} {statistics.median(r[k] for r in rows['this']) / statistics.median(r[k] for r in rows['ref']):.2f}x"
            for k in keys))
    return 0


if __name__ == "__main__":
    sys.exit(main())
