"""gtvo's default ``gtvo run`` and ORB-SLAM3 side by side: interleaved runs on the same logs, one table.

    python benchmarks/vs_orbslam3.py [--runs 3] [--logs kitti,raw] [--peer DIR] [--build DIR]

For every round and every log it runs, one after the other (the order alternating from round to
round, so that a drift of the machine's speed falls on both):

* gtvo: ``python -m gtvo run LOG --out OUT --no-progress`` with this checkout's gtvo (or ``--tree``'s),
  the default settings;
* ORB-SLAM3: the peer's ``run.py --dataset LOG --runs 1`` (``../shared/peers/orbslam3``; built by its
  ``build.sh`` into ``--build``). ORB-SLAM3 is GPL: it is only run as that separate program, never
  imported.

and prints per log the median and range over the rounds of:

* frames/s: gtvo's ``frames_per_second`` (report.json: frames over the seconds of its frame loop),
  ORB-SLAM3's ``fps`` (results.json: frames over its tracking loop, image reading included), and their
  ratio gtvo / ORB-SLAM3;
* CPU ms per frame of the whole process, every thread: gtvo's from the operating system's account of
  the ``gtvo run`` process and the processes it waited for (its window worker), ORB-SLAM3's
  ``process_cpu_s`` (its worker process: tracking, local mapping and loop closing threads);
* whole-process wall seconds, start to outputs written (gtvo: measured here around the process;
  ORB-SLAM3: ``process_s``, vocabulary loading and saving included);
* ATE (m, SE(3)-aligned RMSE): gtvo's ``ate_rmse_m``, ORB-SLAM3's ``ate_final_m`` (n/a without ground truth).

Timings are ratios measured in the same run on the same machine (the load average is printed);
the figures of one run are in ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GTVO_SHARED_DATA", REPO.parent / "shared" / "data"))
LOGS = {
    "kitti": SHARED / "kitti_stereo_sample" / "KITTI_sequence_1",
    "raw": SHARED / "kitti_raw_2011_09_26_drive_0001_stereo",
}
PEER = SHARED.parent / "peers" / "orbslam3"


def run_gtvo(log: Path, out: Path, tree: Path, extra: list[str]) -> dict:
    """One ``gtvo run`` of ``log``: its report's figures and the whole process's wall and CPU."""
    env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg")
    cmd = [sys.executable, "-m", "gtvo", "run", str(log), "--out", str(out), "--no-progress", *extra]
    log_file = out.parent / f"{out.name}.stderr.txt"
    log_file.parent.mkdir(parents=True, exist_ok=True)
    with open(log_file, "w") as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=log)
        _, status, usage = os.wait4(proc.pid, 0)  # usage: the process and the children it waited for
        wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    proc.returncode = code
    if code != 0:
        return {"error": f"gtvo run exit {code}: {log_file.read_text().strip().splitlines()[-1:]}"}
    report = json.loads((out / "report.json").read_text())
    frames = report["frames"]
    return {"fps": report["frames_per_second"], "cpu_ms_per_frame": 1000 * (usage.ru_utime + usage.ru_stime) / frames,
            "process_s": wall, "ate_m": report.get("ate_rmse_m"), "frames": frames,
            "max_rss_mb": usage.ru_maxrss / 1024}


def run_peer(log: Path, out: Path, peer: Path, build: Path | None) -> dict:
    """One ORB-SLAM3 run of ``log`` through the peer's ``run.py`` (a separate program)."""
    cmd = [sys.executable, str(peer / "run.py"), "--dataset", str(log), "--runs", "1", "--out", str(out)]
    if build is not None:
        cmd += ["--build", str(build)]
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    results = out / "results.json"
    if proc.returncode != 0 or not results.exists():
        return {"error": f"ORB-SLAM3 run.py exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}"}
    run = json.loads(results.read_text())["runs"][0]
    if "error" in run:
        return {"error": f"ORB-SLAM3: {run['error']}"}
    return {"fps": run["fps"], "cpu_ms_per_frame": 1000 * run["process_cpu_s"] / run["frames"],
            "process_s": run["process_s"], "ate_m": run.get("ate_final_m"), "frames": run["frames"]}


def spread(values: list[float], fmt: str) -> str:
    """``median (min-max)`` of ``values``; ``n/a`` when there are none."""
    v = [x for x in values if x is not None]
    if not v:
        return "n/a"
    med = fmt.format(statistics.median(v))
    return med if len(v) == 1 else f"{med} ({fmt.format(min(v))}-{fmt.format(max(v))})"


def table(name: str, gtvo: list[dict], peer: list[dict]) -> str:
    """The Markdown table of one log: one row per figure, gtvo | ORB-SLAM3 | ratio."""
    def col(rows: list[dict], key: str) -> list[float]:
        return [r[key] for r in rows if "error" not in r and r.get(key) is not None]
    pairs = [(g, p) for g, p in zip(gtvo, peer) if "error" not in g and "error" not in p]
    lines = [f"{name}: {len(col(gtvo, 'fps'))} gtvo runs, {len(col(peer, 'fps'))} ORB-SLAM3 runs",
             "| figure | gtvo | ORB-SLAM3 | gtvo / ORB-SLAM3 (per round) |", "|---|---|---|---|"]
    for label, key, fmt in (("frames/s", "fps", "{:.1f}"), ("CPU ms/frame, whole process", "cpu_ms_per_frame", "{:.0f}"),
                            ("whole process s", "process_s", "{:.2f}"), ("ATE m", "ate_m", "{:.4f}")):
        ratios = [g[key] / p[key] for g, p in pairs if g.get(key) is not None and p.get(key)]
        lines.append(f"| {label} | {spread(col(gtvo, key), fmt)} | {spread(col(peer, key), fmt)} | "
                     f"{spread(ratios, '{:.2f}')} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="rounds; each runs gtvo and ORB-SLAM3 once per log (default 3)")
    ap.add_argument("--logs", default="kitti,raw", help=f"comma-separated, of {', '.join(LOGS)} (default both)")
    ap.add_argument("--peer", type=Path, default=PEER, help=f"the ORB-SLAM3 peer folder (default {PEER})")
    ap.add_argument("--build", type=Path, default=None, help="the peer's build folder (default its own: /tmp/peer-orbslam3)")
    ap.add_argument("--tree", type=Path, default=REPO, help="the gtvo checkout to run (default this one)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/gtvo_vs_orbslam3"), help="output folder")
    ap.add_argument("--gtvo-arg", action="append", default=[], metavar="ARG",
                    help="an extra argument of gtvo run (repeat it; e.g. --gtvo-arg=--no-parallel)")
    a = ap.parse_args()
    names = [n.strip() for n in a.logs.split(",") if n.strip()]
    unknown = [n for n in names if n not in LOGS]
    if unknown or a.runs < 1:
        print(f"vs_orbslam3: error: unknown log {unknown[0]!r} (use {', '.join(LOGS)})" if unknown
              else f"vs_orbslam3: error: --runs must be >= 1, got {a.runs}", file=sys.stderr)
        return 2
    for n in names:
        if not LOGS[n].is_dir():
            print(f"vs_orbslam3: error: {LOGS[n]}: no such log folder", file=sys.stderr)
            return 2
    results: dict[str, dict[str, list[dict]]] = {n: {"gtvo": [], "orbslam3": []} for n in names}
    print(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores", flush=True)
    for r in range(a.runs):
        for n in names:
            order = ("gtvo", "orbslam3") if r % 2 == 0 else ("orbslam3", "gtvo")
            for who in order:
                out = a.out / n / who / f"run{r + 1}"
                res = (run_gtvo(LOGS[n], out, a.tree, a.gtvo_arg) if who == "gtvo"
                       else run_peer(LOGS[n], out, a.peer, a.build))
                results[n][who].append(res)
                shown = res.get("error") or (f"{res['fps']:.1f} frames/s, {res['cpu_ms_per_frame']:.0f} ms CPU/frame, "
                                             f"{res['process_s']:.2f} s process")
                print(f"round {r + 1} {n} {who}: {shown}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}\n")
    for n in names:
        print(table(f"{n} ({LOGS[n].name})", results[n]["gtvo"], results[n]["orbslam3"]) + "\n")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "summary.json").write_text(json.dumps(results, indent=1))
    failed = [r for n in names for who in results[n].values() for r in who if "error" in r]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
