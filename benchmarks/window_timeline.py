"""Where the parallel window's time goes: the front end's waits and the worker's idles, per message,
and what the same schedule gives on two idle cores.

    python benchmarks/window_timeline.py [--log DIR] [--frames N] [--window-scale 0.5,1] [--modes auto,parallel]

Runs ``gtvo run``'s default configuration on the preloaded frames of a log (KITTI_sequence_1 by
default) sequentially (``window.parallel: false``) and in each of ``--modes`` (``auto``: the schedule
moves the window to its worker at its decision keyframe; ``parallel``: the worker from the start),
alternating, and records the front end's sends and waits
(:class:`gtvo.odometry.window_worker.FrontEndEvent`, with its CPU clock) and the worker's spans
(:class:`gtvo.odometry.window_worker.MessageSpan`: each message's CPU, its start's included).

On a machine shared by other jobs wall time means little, so the script *replays* the run's
schedule on two idle cores from the CPU it measured: the front end runs its CPU between events,
a message reaches the worker when it is sent, the worker handles its messages in order, each for
its measured CPU, and a wait ends when its reply is done. The replay's length against the
sequential run's CPU is the speed-up this schedule allows (the determinism rule's waits
included); ``--window-scale`` replays it with every window message (joins and optimisations) at
that fraction of its CPU: what ``auto`` gives once the window is cheaper, the schedule unchanged.
Printed per mode: CPU of both processes against the sequential run's (and the worker's start, the
move's pickle), the messages' pickled bytes and the front end's CPU in its sends and waits, the replayed frames/s ratio per scale, the front end's replayed waits and the
worker's idles, and where the extra CPU goes (the worker's CPU by message kind).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.vo_bench import KITTI_SEQUENCE_1, load_frames  # noqa: E402
from gtvo.config import OdometryConfig  # noqa: E402
from gtvo.core.timing import StageClock  # noqa: E402
from gtvo.datasets import open_sequence  # noqa: E402
from gtvo.odometry import VisualOdometry  # noqa: E402
from gtvo.odometry import window_worker  # noqa: E402
from gtvo.odometry.window_worker import LAG, FrontEndEvent, MessageSpan, WindowWorker  # noqa: E402

#: messages that carry the window's work (scaled by ``--window-scale``)
WINDOW_MESSAGES = ("join", "optimize")
#: the stage clock's window stages (a window in the front end's process: scaled by ``--window-scale``)
WINDOW_STAGES = ("window_build", "linearisation", "solve", "marginalisation", "covariances")


def config_for(parallel: bool | str) -> OdometryConfig:
    """``gtvo run``'s default configuration with ``window.parallel`` set."""
    base = OdometryConfig()
    return dataclasses.replace(base, window=dataclasses.replace(base.window, parallel=parallel))


def one_run(camera: Any, frames: list, parallel: bool | str) -> dict[str, Any]:
    """One run; the front end's CPU, its events and the worker's spans (None: no worker)."""
    vo = VisualOdometry(camera, config_for(parallel))
    vo.clock = StageClock(timer=time.process_time)
    worker = vo.window if isinstance(vo.window, WindowWorker) else None
    try:
        cpu0, wall0 = time.process_time(), time.perf_counter()
        for f in frames:
            vo.process(f)
        vo.finish()
        cpu1, wall1 = time.process_time(), time.perf_counter()
        if isinstance(vo.window, WindowWorker):
            worker = vo.window
        events = [] if worker is None else list(worker.events)  # the run's (not the questions below)
        spans = worker.timeline() if worker is not None else None
        usage = worker.worker_usage() if worker is not None else None
    finally:
        vo.close()
    return {"cpu0": cpu0, "cpu1": cpu1, "wall": wall1 - wall0, "frames": len(frames),
            "events": events, "spans": spans,
            "started": None if worker is None else worker.started,
            "stages": dict(vo.clock.snapshot()),
            "worker_stages": None if usage is None else usage.seconds_by_stage}


def replay(run: dict[str, Any], scale: float = 1.0, lag: int = LAG, rows: list[str] | None = None,
           contention: float = 0.0) -> dict[str, float]:
    """The run's schedule on two idle cores (module docstring): seconds, the front end's waits, the
    worker's idle seconds between its first and last message. ``lag``: the waits the run made
    :data:`LAG` messages behind its last send are replayed ``lag`` behind instead (the waits at once
    stay; the results, which would change with the lag, are not replayed). ``rows``: one line per
    message appended (sent at, worker start and end, the worker's idle before it, the front end's
    wait for it), in replayed seconds."""
    spans: list[MessageSpan] = run["spans"]
    events: list[FrontEndEvent] = run["events"]
    local_window = sum(run["stages"].get(k, 0.0) for k in WINDOW_STAGES)  # the window in this process
    if spans is None:
        return {"seconds": run["cpu1"] - run["cpu0"] - (1 - scale) * local_window, "waits": 0.0, "idle": 0.0}
    start_cpu = run["started"][1] - run["cpu0"]  # when (front end CPU) the worker was asked for
    t_front, cpu_prev = start_cpu, run["started"][1]
    slow = 1.0 + contention
    worker_free = start_cpu + slow * spans[0].cpu_seconds  # the worker's start: imports, its window, warm-up
    messages = spans[1:]
    arrival: dict[int, float] = {}
    done: dict[int, float] = {}
    next_message = 0
    waits = idle = 0.0

    def run_worker_until(number: int) -> None:
        nonlocal worker_free, next_message, idle
        while next_message <= number:
            span = messages[next_message]
            cost = slow * span.cpu_seconds * (scale if span.kind in WINDOW_MESSAGES else 1.0)
            begin = max(worker_free, arrival[next_message])
            idle += begin - worker_free
            if rows is not None:
                rows.append(f"{next_message:4d} {span.kind:9s} sent {arrival[next_message]:7.3f} worker "
                            f"{begin:7.3f}-{begin + cost:7.3f} (idle before {begin - worker_free:6.3f})")
            worker_free = begin + cost
            done[next_message] = worker_free
            next_message += 1

    last_sent = -1
    for ev in events:
        t_front += slow * (ev.cpu - cpu_prev)
        cpu_prev = ev.cpu
        if ev.kind == "send":
            arrival[ev.number] = t_front
            last_sent = ev.number
        else:
            number = ev.number
            if number == last_sent - LAG:
                number = last_sent - lag
            if number < 0:
                continue
            run_worker_until(number)
            if done[number] > t_front:
                if rows is not None:
                    rows.append(f"     front end waits {done[number] - t_front:6.3f} at {t_front:7.3f} for {number}")
                waits += done[number] - t_front
                t_front = done[number]
    t_front += slow * (run["cpu1"] - cpu_prev)
    # the window's stages in this process ran before the move (auto), the schedule then sequential
    return {"seconds": t_front - (1 - scale) * local_window, "waits": waits, "idle": idle}


def by_kind(spans: list[MessageSpan]) -> dict[str, float]:
    """The worker's CPU seconds by message kind."""
    out: dict[str, float] = {}
    for s in spans:
        out[s.kind] = out.get(s.kind, 0.0) + s.cpu_seconds
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", default=str(KITTI_SEQUENCE_1))
    ap.add_argument("--frames", type=int, default=0, help="first N frames (0: all)")
    ap.add_argument("--modes", default="auto", help="parallel modes beside the sequential one: auto, parallel")
    ap.add_argument("--window-scale", default="1,0.5", help="window message CPU factors replayed")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--per-message", action="store_true", help="print the replayed timeline (window x1, the run's lag)")
    ap.add_argument("--contention", default="0", help="replayed with both processes' CPU at 1 + C once the worker "
                    "is asked for (comma-separated; a bound, see replay)")
    ap.add_argument("--lags", default=str(LAG), help="lags replayed (the run's own: gtvo.odometry.window_worker.LAG)")
    args = ap.parse_args()
    window_worker.STAGE_TIMER = time.process_time  # the forked worker's stages in CPU seconds
    seq = open_sequence(args.log)
    frames = load_frames(seq, progress=False)
    if args.frames:
        frames = frames[:args.frames]
    modes = {"auto": "auto", "parallel": True}
    chosen = [m for m in args.modes.split(",") if m]
    scales = [float(x) for x in args.window_scale.split(",")]
    one_run(seq.camera, frames[:8], False)  # warm-up: kernels loaded
    print(f"# {args.log}, {len(frames)} frames, load {os.getloadavg()[0]:.1f}")
    for r in range(args.repeat):
        seqrun = one_run(seq.camera, frames, False)
        seq_cpu = seqrun["cpu1"] - seqrun["cpu0"]
        print(f"round {r + 1}: sequential CPU {seq_cpu:.2f} s ({1000 * seq_cpu / len(frames):.1f} ms/frame), "
              f"wall {seqrun['wall']:.1f} s; stages (CPU s): "
              + ", ".join(f"{k} {v:.2f}" for k, v in seqrun["stages"].items() if v > 0.005))
        for name in chosen:
            run = one_run(seq.camera, frames, modes[name])
            front = run["cpu1"] - run["cpu0"]
            spans = run["spans"] or []
            worker = sum(s.cpu_seconds for s in spans)
            kinds = by_kind(spans)
            print(f"  {name}: CPU front end {front:.2f} + worker {worker:.2f} = {front + worker:.2f} s "
                  f"({(front + worker) / seq_cpu:.3f}x sequential), wall {run['wall']:.1f} s; worker by message "
                  + ", ".join(f"{k} {v:.2f}" for k, v in kinds.items()))
            sent = [e for e in run["events"] if e.kind == "send"]
            got = [e for e in run["events"] if e.kind == "wait"]
            print(f"    messages: {len(sent)} sent, {sum(e.nbytes for e in sent) / 1024:.0f} KiB pickled, "
                  f"{1000 * sum(e.cpu_seconds for e in sent):.0f} ms of the front end's CPU; replies "
                  f"{sum(e.nbytes for e in got) / 1024:.0f} KiB, {1000 * sum(e.cpu_seconds for e in got):.0f} ms "
                  "of its CPU in its waits (reading, unpickling)")
            move = [e for e in run["events"]][:1]
            if run["started"] is not None:
                print(f"    worker asked for at front-end CPU {run['started'][1] - run['cpu0']:.2f} s "
                      f"(first send {move[0].cpu - run['started'][1]:.3f} s of CPU later)" if move else "")
            stages = run["stages"]
            print("    front end stages (CPU s): " + ", ".join(f"{k} {v:.2f}" for k, v in stages.items() if v > 0.005))
            if run["worker_stages"]:
                print("    worker stages (CPU s): " + ", ".join(f"{k} {v:.2f}" for k, v in run["worker_stages"].items()
                                                           if v > 0.005))
            if args.per_message:
                lines: list[str] = []
                replay(run, 1.0, LAG, lines)
                print("\n".join("      " + line for line in lines))
            for scale, lag, c in ((x, int(n), float(c)) for x in scales for n in args.lags.split(",")
                                  for c in args.contention.split(",")):
                rp = replay(run, scale, lag, contention=c)
                seq_scaled = replay(seqrun, scale)["seconds"]
                print(f"    window x{scale:g}, lag {lag}, contention {c:g}: replay {rp['seconds']:.2f} s -> {seq_scaled / rp['seconds']:.3f}x the "
                      f"sequential frames/s (sequential {seq_scaled:.2f} s); front end waits {rp['waits']:.2f} s, "
                      f"worker idle {rp['idle']:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
