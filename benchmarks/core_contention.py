"""Does the same work cost more CPU when both of this machine's cores are busy?

    python benchmarks/core_contention.py --toggle [--seconds 40] [--kernels ...] [--partner KERNEL]
    python benchmarks/core_contention.py [--rounds 3] [--seconds 4] [--kernels warp,arith,python,memory,gather]
    python benchmarks/core_contention.py --processes [--rounds 2] [--cores one,two] [--log kitti|raw] [--no-peer]
    python benchmarks/core_contention.py --sample SECONDS [--duty 0.125] [--out FILE]

The figures of 2026-11-29 are in docs/benchmarks.md ("Two cores at once") and docs/window.md.

Toggle mode (``--toggle``, the one to trust on a shared machine): a kernel pinned to the first core
runs without a pause while the same kernel (or ``--partner``) on the second core runs for half a
second and sleeps for half a second, in turn; the first kernel's CPU per repetition in each "on"
half over the two "off" halves around it. The machine's own drift (the same loop's cost changes by
up to 1.4x between runs minutes apart) is slower than a second and cancels in each pair. On a
loaded machine each process gets a share of its core (printed) and the contrast is that share's;
``--realtime`` runs both at real-time priority (``chrt -f 10``: each holds its core, the other jobs
wait, for ``--seconds`` per kernel) and the second process spends its "off" halves on a
register-only loop: the contrast is then a memory-hungry neighbour against a quiet one, whatever
the load.

Kernels: a fixed piece of work run over and over,

* ``warp``: gtvo's residual kernel (``factors._compiled.warp_into`` through ``photometric_residuals``):
  2000 StereoSGBM points of KITTI_sequence_1's frame 0 warped into frame 1 with Jacobians;
* ``arith``: a compiled scalar loop of dependent floating-point arithmetic (registers only);
* ``python``: an interpreter loop of integer arithmetic (the Python between gtvo's compiled calls);
* ``memory``: numpy ``a + b -> c`` over three 128 MB arrays (beyond the caches: memory bound),
* ``gather``: a compiled loop of random reads from an 8 MB table (beyond a core's L2, within the L3),

Kernel mode (the default): each kernel for ``--seconds`` of wall time in three set-ups,
alternately (the order turns from round to round):

* ``solo``: one process, on the first core (``taskset -c 0``);
* ``pair pinned``: two processes at once, ``taskset`` one to each core;
* ``pair free``: two processes at once, placed by the scheduler.

Each process imports and warms its kernel, then all start together and each counts its repetitions
and its own CPU time (``time.process_time``) over the same wall interval. The figure is the CPU
microseconds per repetition (the cost of a fixed piece of work: the kernel is the same in every
set-up), and its ratio pair / solo. As the machine is shared, a "solo" process may have had the
other core busy with someone else's work: each pinned process also samples, every 0.25 s, its own
cost and the other core's busy fraction (``/proc/stat``), and the table fits the cost against that
fraction (busy / idle: the line at 1 over the line at 0; and the windows above 0.8 over those
below 0.2). The operating system's own steal time (``/proc/stat``: time
the hypervisor ran something else on the virtual core; not counted in a process's CPU time on this
kernel) and the CPU of processes other than ours (the machine is shared) are printed per set-up.
Hardware counters (``perf stat -e instructions``) are not exposed by this virtual machine.

Process mode (``--processes``): whole programs run on one core (``taskset -c 0``: their threads and
processes never run at the same time) and on both, alternately, their total CPU (user + sys of
every thread and waited-for child) and minor page faults compared: ``gtvo run`` on KITTI_sequence_1
with ``--no-parallel``, ``window.parallel: auto`` and ``--parallel`` (front end and window worker),
and ORB-SLAM3 (tracking and local mapping threads; the peer's ``run.py``, as
``benchmarks/vs_orbslam3.py`` runs it) if its build is there. A program whose CPU is the same on
one core as on two pays nothing for running its parts at once; the same work done on one core
cannot have been slowed by the other core. ``--cores two --no-peer --gtvo-modes no-parallel,auto``
compares the modes' frames/s and CPU on two cores, per round.

Sample mode (``--sample``): the kernels on the first core, a quarter second each in turn at a low
duty, against the other core's busy fraction: the contrast whenever the shared machine's other core
happens to idle (it did not, on 2026-11-29).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("GTVO_SHARED_DATA", REPO.parent / "shared" / "data"))
KITTI = SHARED / "kitti_stereo_sample" / "KITTI_sequence_1"
LOGS = {"kitti": KITTI, "raw": SHARED / "kitti_raw_2011_09_26_drive_0001_stereo"}
PEER = SHARED.parent / "peers" / "orbslam3"
KERNELS = ("warp", "arith", "python", "memory", "gather")
SETUPS = ("solo", "pair pinned", "pair free")
WINDOW_S = 0.25  #: wall seconds of one sample window in a child
HALF_PERIOD_S = 0.5  #: ``--toggle``: the second core's process is on, then off, for this long each


# ---------------------------------------------------------------- the kernels (run in a child)

def make_spin():
    """A compiled loop of ``n`` steps of dependent floating-point arithmetic (registers only), compiled."""
    import numba

    @numba.njit(cache=False)
    def spin(n: int) -> float:
        x, y = 1.0, 0.5
        for _ in range(n):
            x = x * 0.999999 + y * 1e-6
            y = y * 0.999998 + x * 2e-6
        return x + y
    spin(10)
    return spin


def make_kernel(name: str):
    """A function doing one repetition of the fixed work ``name`` (set up and warmed here)."""
    if name == "warp":
        sys.path.insert(0, str(REPO))
        import gtsam
        import numpy as np

        from benchmarks._kitti_sgbm import load_kitti, read_gray, sgbm_keyframe_points
        from factors.photometric import (
            GradientImage,
            pattern_bearings,
            photometric_residuals,
            sample_host,
        )
        stereo, lefts, rights, gt = load_kitti(KITTI)
        left0 = read_gray(lefts[0])
        px, d, _ = sgbm_keyframe_points(left0, read_gray(rights[0]), stereo, 2000)
        host, target = GradientImage(left0), GradientImage(read_gray(lefts[1]))
        Ih, hv = sample_host(host, px)
        f = pattern_bearings(stereo.left, px)
        Th, Tt = gtsam.Pose3(gt[0]), gtsam.Pose3(gt[1]).retract(np.array([0.002, -0.001, 0.001, 0.02, -0.01, 0.03]))

        def warp() -> None:
            photometric_residuals(stereo.left, Ih, hv, px, d, Th, Tt, target, bearings=f)
        return warp
    if name == "arith":
        spin = make_spin()
        return lambda: spin(2_000_000)
    if name == "python":
        def loop() -> None:
            x = 1
            for i in range(20_000):
                x = (x * 1103515245 + 12345 + i) & 0xFFFFFFFF
        return loop
    if name == "memory":
        import numpy as np
        n = 16 * 1024 * 1024  # 128 MB of float64 each
        a, b, c = np.ones(n), np.full(n, 2.0), np.empty(n)

        def stream() -> None:
            np.add(a, b, out=c)
        return stream
    if name == "gather":
        import numba
        import numpy as np

        @numba.njit(cache=False)
        def gather(table, index) -> float:
            acc = 0.0
            for i in index:
                acc += table[i]
            return acc
        rng = np.random.default_rng(0)
        table = rng.random(2 * 1024 * 1024).astype(np.float32)  # 8 MB: beyond a core's L2, within the L3
        index = rng.integers(0, table.size, 200_000)
        gather(table, index[:10])
        return lambda: gather(table, index)
    raise ValueError(f"unknown kernel {name!r}")


def cpu_busy() -> list[int]:
    """Busy ticks (user, nice, system, irq, softirq) of each core, from ``/proc/stat``."""
    with open("/proc/stat") as fh:
        lines = [ln.split() for ln in fh if ln.startswith("cpu") and ln[3].isdigit()]
    return [sum(int(x) for x in (v[1], v[2], v[3], v[6], v[7])) for v in lines]


def child(name: str, seconds: float) -> None:
    """Set up ``name``, warm it, say ``ready``, wait for the go line, then run it for ``seconds``,
    in windows of ``WINDOW_S``: each window's repetitions, own CPU, wall and the cores' busy ticks."""
    fn = make_kernel(name)
    for _ in range(3):
        fn()
    print("ready", flush=True)
    sys.stdin.readline()
    w0, c0 = time.perf_counter(), time.process_time()
    deadline = w0 + seconds
    windows = []
    while time.perf_counter() < deadline:
        ws, cs, bs = time.perf_counter(), time.process_time(), cpu_busy()
        reps = 0
        while time.perf_counter() - ws < WINDOW_S:
            fn()
            reps += 1
        windows.append({"reps": reps, "cpu_s": time.process_time() - cs, "wall_s": time.perf_counter() - ws,
                        "busy": [b - a for a, b in zip(bs, cpu_busy())], })
    reps = sum(w["reps"] for w in windows)
    print(json.dumps({"reps": reps, "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
                      "windows": windows}), flush=True)


def toggle_child(name: str, seconds: float, role: str) -> None:
    """``--toggle``'s processes: ``measure`` runs ``name`` without a pause and records its cost per
    half period; ``toggle`` runs it in the even half periods and sleeps in the odd ones. Both count
    the half periods from the same start (the go line's monotonic time, shared by the processes)."""
    fn = make_kernel(name)
    for _ in range(3):
        fn()
    quiet = make_spin() if role == "quiet" else None
    print("ready", flush=True)
    t0 = float(sys.stdin.readline())
    halves = int(seconds / HALF_PERIOD_S)
    while time.perf_counter() < t0:
        time.sleep(0.001)
    out = []
    for k in range(halves):
        end = t0 + (k + 1) * HALF_PERIOD_S
        if role == "toggle" and k % 2:
            time.sleep(max(0.0, end - time.perf_counter()))
            continue
        if role == "quiet" and k % 2:  # the off half on a register-only loop: the core held, no memory traffic
            while time.perf_counter() < end:
                quiet(100_000)
            continue
        c, reps = time.process_time(), 0
        while time.perf_counter() < end:
            fn()
            reps += 1
        out.append((k, reps, time.process_time() - c))
    print(json.dumps(out), flush=True)


def on_off_ratios(halves: list[tuple[int, int, float]]) -> tuple[list[float], list[float]]:
    """From the measuring process's ``(half, repetitions, CPU s)``: per "on" half (even) with both
    neighbours measured, its CPU per repetition over the mean of its two "off" neighbours'; and the
    "off" halves' CPU per repetition. Halves without a repetition are left out."""
    cost = {h: c / n for h, n, c in halves if n}
    ratios = [cost[h] / (0.5 * (cost[h - 1] + cost[h + 1])) for h in sorted(cost)
              if h % 2 == 0 and h - 1 in cost and h + 1 in cost]
    return ratios, [c for h, c in sorted(cost.items()) if h % 2]


def toggle_mode(a: argparse.Namespace) -> int:
    """``--toggle``: a kernel on the first core without a pause, and the same (or ``--partner``) on
    the second core on and off every :data:`HALF_PERIOD_S`; the first core's cost per repetition in the halves with the
    second core on over the halves around them with it off (the machine's own drift, slower than a
    second, cancels in each pair)."""
    kernels = [k.strip() for k in a.kernels.split(",") if k.strip()]
    print(f"load average before: {os.getloadavg()[0]:.2f}; {a.seconds:g} s per kernel, halves of {HALF_PERIOD_S} s", flush=True)
    print("| kernel | us CPU/rep, other core off | on / off (median of pairs, quartiles) | pairs | CPU share: measured, partner on |")
    print("|---|---|---|---|---|")
    for k in kernels:
        partner = a.partner or k
        rt = ["chrt", "-f", "10"] if a.realtime else []
        procs = [subprocess.Popen([*rt, "taskset", "-c", str(i), sys.executable, __file__, "--child", kk, "--seconds",
                                   str(a.seconds), "--role", role], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
                 for i, (role, kk) in enumerate((("measure", k), ("quiet" if a.realtime else "toggle", partner)))]
        for p in procs:
            if p.stdout.readline().strip() != "ready":
                raise RuntimeError(f"{k}: a child did not start")
        t0 = time.perf_counter() + 0.2
        for p in procs:
            p.stdin.write(f"{t0!r}\n")
            p.stdin.flush()
        halves = json.loads(procs[0].stdout.readline())
        partner_halves = json.loads(procs[1].stdout.readline())
        for p in procs:
            p.wait()
        ratios, off = on_off_ratios(halves)
        # how much of its "on" halves the partner ran, and of every half the measured kernel (a loaded
        # machine gives each a share: the contrast is then that share's)
        partner_share = statistics.mean(c / HALF_PERIOD_S for _, _, c in partner_halves) if partner_halves else 0.0
        own_share = statistics.mean(c / HALF_PERIOD_S for _, _, c in halves) if halves else 0.0
        if not ratios:
            print(f"| {k} | n/a | n/a | 0 | |")
            continue
        q = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else ratios * 3
        print(f"| {k}{'' if partner == k else ' beside ' + partner} | {1e6 * statistics.median(off):.0f} | {statistics.median(ratios):.3f} ({q[0]:.3f}-{q[2]:.3f}) | "
              f"{len(ratios)} | {own_share:.2f}, {partner_share:.2f} |", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


# ---------------------------------------------------------------- the parent

def proc_stat() -> tuple[int, int]:
    """(busy ticks of both cores, steal ticks) from ``/proc/stat``."""
    with open("/proc/stat") as fh:
        v = [int(x) for x in fh.readline().split()[1:]]
    user, nice, system, _idle, _iowait, irq, softirq, steal = v[:8]
    return user + nice + system + irq + softirq, steal


def run_setup(kernel: str, setup: str, seconds: float) -> dict:
    """One set-up of one kernel: its processes' repetitions and CPU, the steal and the others' CPU."""
    n = 1 if setup == "solo" else 2
    cmds = []
    for i in range(n):
        pin = ["taskset", "-c", str(i)] if setup != "pair free" else []
        cmds.append(pin + [sys.executable, __file__, "--child", kernel, "--seconds", str(seconds)])
    procs = [subprocess.Popen(c, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) for c in cmds]
    for p in procs:
        if p.stdout.readline().strip() != "ready":
            raise RuntimeError(f"{kernel}: a child did not start")
    hz = os.sysconf("SC_CLK_TCK")
    b0, s0 = proc_stat()
    for p in procs:
        p.stdin.write("go\n")
        p.stdin.flush()
    out = [json.loads(p.stdout.readline()) for p in procs]
    b1, s1 = proc_stat()
    for p in procs:
        p.wait()
    ours = sum(o["cpu_s"] for o in out)
    wall = max(o["wall_s"] for o in out)
    samples = []  # (the other core's busy fraction, us CPU per rep) of each window of a pinned child
    if setup != "pair free":
        for i, o in enumerate(out):
            samples += [(w["busy"][1 - i] / hz / w["wall_s"], 1e6 * w["cpu_s"] / w["reps"]) for w in o["windows"] if w["reps"]]
    return {"us_per_rep": statistics.mean(1e6 * o["cpu_s"] / o["reps"] for o in out), "samples": samples,
            "cpu_per_wall": ours / wall / n,
            "steal": (s1 - s0) / hz / wall, "others": max(0.0, (b1 - b0) / hz - ours) / wall}


def busy_ratio(samples: list[tuple[float, float]]) -> str:
    """The CPU per repetition with the other core busy over that with it idle: the least-squares line
    of cost against the other core's busy fraction, at 1 over at 0; and the mean cost of the windows
    with the other core above 0.8 busy over that of those below 0.2 (their counts)."""
    import numpy as np
    if len(samples) < 3:
        return "n/a"
    x, y = np.array(samples).T
    x = np.clip(x, 0.0, 1.0)
    lo, hi = y[x < 0.2], y[x > 0.8]
    if len(lo) < 3 or len(hi) < 3:  # no contrast: a line through one end says nothing
        return f"n/a ({len(hi)}/{len(lo)})"
    b, a = np.polyfit(x, y, 1)
    bins = f"{hi.mean() / lo.mean():.2f} ({len(hi)}/{len(lo)})" if len(lo) and len(hi) else f"n/a ({len(hi)}/{len(lo)})"
    return f"{(a + b) / a:.2f}; {bins}"


def kernels_mode(a: argparse.Namespace) -> int:
    kernels = [k.strip() for k in a.kernels.split(",") if k.strip()]
    bad = [k for k in kernels if k not in KERNELS]
    if bad:
        print(f"core_contention: error: unknown kernel {bad[0]!r} (use {', '.join(KERNELS)})", file=sys.stderr)
        return 2
    res: dict = {k: {s: [] for s in SETUPS} for k in kernels}
    print(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} cores; {a.seconds} s per set-up", flush=True)
    for r in range(a.rounds):
        order = SETUPS if r % 2 == 0 else SETUPS[::-1]
        for k in kernels:
            for s in order:
                x = run_setup(k, s, a.seconds)
                res[k][s].append(x)
                print(f"round {r + 1} {k:6s} {s:11s}: {x['us_per_rep']:9.1f} us CPU/rep, CPU/wall {x['cpu_per_wall']:.2f}, "
                      f"steal {x['steal']:.2f} cores, others {x['others']:.2f} cores", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}\n")
    print("| kernel | solo us CPU/rep | pair pinned / solo | pair free / solo | other core busy / idle (fit; windows) "
          "| steal (cores) solo, pair | others' CPU (cores) |")
    print("|---|---|---|---|---|---|---|")
    for k in kernels:
        solo = [x["us_per_rep"] for x in res[k]["solo"]]
        ratios = {}
        for s in SETUPS[1:]:
            rr = [x["us_per_rep"] / y for x, y in zip(res[k][s], solo)]
            ratios[s] = f"{statistics.median(rr):.2f} ({min(rr):.2f}-{max(rr):.2f})"
        st = [statistics.mean(x["steal"] for x in res[k][s]) for s in ("solo", "pair pinned")]
        ot = max(x["others"] for s in SETUPS for x in res[k][s])
        fit = busy_ratio([xy for s in SETUPS for x in res[k][s] for xy in x["samples"]])
        print(f"| {k} | {statistics.median(solo):.0f} ({min(solo):.0f}-{max(solo):.0f}) | {ratios['pair pinned']} | "
              f"{ratios['pair free']} | {fit} | {st[0]:.2f}, {st[1]:.2f} | <= {ot:.2f} |")
    return 0


def sample_mode(a: argparse.Namespace) -> int:
    """``--sample``: the kernels on the first core, one window of ``WINDOW_S`` each in turn, one
    window in ``1 / --duty`` of the time (a light load), each window's cost against the other
    core's busy fraction; the contrast a shared machine gives whenever the other core idles."""
    kernels = [k.strip() for k in a.kernels.split(",") if k.strip()]
    os.sched_setaffinity(0, {0})
    fns = {k: make_kernel(k) for k in kernels}
    for fn in fns.values():
        fn()
    hz = os.sysconf("SC_CLK_TCK")
    samples: dict = {k: [] for k in kernels}
    end = time.perf_counter() + a.sample
    print(f"sampling {a.sample:.0f} s, duty {a.duty:g}, load {os.getloadavg()[0]:.2f}", flush=True)
    while time.perf_counter() < end:
        for k, fn in fns.items():
            ws, cs, bs = time.perf_counter(), time.process_time(), cpu_busy()
            reps = 0
            while time.perf_counter() - ws < WINDOW_S:
                fn()
                reps += 1
            wall = time.perf_counter() - ws
            busy = [b - x for x, b in zip(bs, cpu_busy())]
            samples[k].append((busy[1] / hz / wall, 1e6 * (time.process_time() - cs) / reps))
            time.sleep(WINDOW_S * (1.0 / a.duty - 1.0))
        if a.out:  # so far (a long sampling may be read before it ends)
            Path(a.out).write_text(json.dumps(samples))
    print("| kernel | us CPU/rep, median | other core busy / idle (fit; windows >0.8/<0.2) |")
    print("|---|---|---|")
    for k in kernels:
        print(f"| {k} | {statistics.median(y for _, y in samples[k]):.0f} | {busy_ratio(samples[k])} |")
    if a.out:
        Path(a.out).write_text(json.dumps(samples))
    return 0


def timed(cmd: list[str], env: dict | None = None) -> dict:
    """Exit code, wall s, CPU s (user, sys) and minor page faults of the process and the children it waited for."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, ru = os.wait4(p.pid, 0)
    return {"code": os.waitstatus_to_exitcode(status), "wall": time.perf_counter() - t0, "user": ru.ru_utime,
            "sys": ru.ru_stime, "cpu": ru.ru_utime + ru.ru_stime, "minflt": ru.ru_minflt}


def processes_mode(a: argparse.Namespace) -> int:
    tmp = Path(tempfile.mkdtemp(prefix="core_contention_"))
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    auto = tmp / "auto.yaml"
    auto.write_text("window:\n  parallel: auto\n")
    log = LOGS[a.log]
    gtvo = [sys.executable, "-m", "gtvo", "run", str(log), "--no-progress"]
    progs = {}
    for mode in a.gtvo_modes.split(","):
        extra = {"no-parallel": ["--no-parallel"], "auto": ["--config", str(auto)], "parallel": ["--parallel"]}[mode]
        progs[f"gtvo {mode}"] = lambda out, extra=extra: (gtvo + ["--out", str(out)] + extra, env)
    build = a.build if a.build is not None else Path("/tmp/peer-orbslam3")
    if a.no_peer:
        pass
    elif (a.peer / "run.py").exists() and (build / "venv").exists():
        progs["ORB-SLAM3"] = lambda out: ([sys.executable, str(a.peer / "run.py"), "--dataset", str(log), "--runs", "1",
                                           "--out", str(out), "--build", str(build)], None)
    else:
        print(f"ORB-SLAM3 skipped: no {a.peer / 'run.py'} or no build at {build}")
    setups = [f"{c} core{'s' if c == 'two' else ''}" for c in a.cores.split(",")]
    res: dict = {p: {s: [] for s in setups} for p in progs}
    print(f"{log.name}; load average before: {os.getloadavg()[0]:.2f}", flush=True)
    for r in range(a.rounds):
        order = setups if r % 2 == 0 else setups[::-1]
        names = list(progs) if r % 2 == 0 else list(progs)[::-1]
        for name in names:
            for s in order:
                out = tmp / f"{name.replace(' ', '_')}_{s.replace(' ', '_')}_{r}"
                cmd, e = progs[name](out)
                pin = ["taskset", "-c", "0"] if s == "one core" else []
                x = timed((["chrt", "-f", "10"] if a.realtime else []) + pin + cmd, e)
                if x["code"] == 0 and name == "ORB-SLAM3":
                    run = json.loads((out / "results.json").read_text())["runs"][0]
                    x["cpu"], x["fps"] = run["process_cpu_s"], run["fps"]  # its worker process, not run.py's
                elif x["code"] == 0:
                    x["fps"] = json.loads((out / "report.json").read_text())["frames_per_second"]
                res[name][s].append(x if x["code"] == 0 else None)
                print(f"round {r + 1} {name} {s}: exit {x['code']}, {x.get('fps', 0):.2f} frames/s, wall {x['wall']:.2f} s, CPU {x['cpu']:.2f} s "
                      f"(sys {x['sys']:.2f}), minor faults {x['minflt']}, load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}\n")
    if len(setups) == 1:  # the programs against the first one, per round (frames/s and CPU)
        first = next(iter(progs))
        print(f"| program | frames/s | x {first} (per round) | CPU s | x {first} (per round) |")
        print("|---|---|---|---|---|")
        for name in progs:
            pairs = [(x, y) for x, y in zip(res[first][setups[0]], res[name][setups[0]]) if x and y]
            if not pairs:
                print(f"| {name} | failed | | | |")
                continue
            cells = []
            for k in ("fps", "cpu"):
                rr = [y[k] / x[k] for x, y in pairs]
                cells.append(f"{statistics.median(y[k] for _, y in pairs):.2f} | {statistics.median(rr):.3f} "
                             f"({min(rr):.3f}-{max(rr):.3f})")
            print(f"| {name} | {cells[0]} | {cells[1]} |")
        return 0
    print("| program | CPU s one core | CPU s two cores | two / one (per round) | sys s one, two | minor faults one, two |")
    print("|---|---|---|---|---|---|")
    for name in progs:
        pairs = [(x, y) for x, y in zip(res[name]["one core"], res[name]["two cores"]) if x and y]
        if not pairs:
            print(f"| {name} | failed | failed | n/a | | |")
            continue
        rr = [y["cpu"] / x["cpu"] for x, y in pairs]
        def med(k: str, i: int, pairs: list = pairs) -> float:
            return statistics.median(p[i][k] for p in pairs)
        print(f"| {name} | {med('cpu', 0):.2f} | {med('cpu', 1):.2f} | {statistics.median(rr):.2f} ({min(rr):.2f}-{max(rr):.2f}) | "
              f"{med('sys', 0):.2f}, {med('sys', 1):.2f} | {med('minflt', 0):.0f}, {med('minflt', 1):.0f} |")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=4.0, help="wall seconds per set-up and kernel (default 4)")
    ap.add_argument("--kernels", default=",".join(KERNELS), help=f"comma-separated, of {', '.join(KERNELS)}")
    ap.add_argument("--processes", action="store_true", help="whole programs on one core against two (see above)")
    ap.add_argument("--gtvo-modes", default="no-parallel,auto,parallel",
                    help="gtvo run's window.parallel modes in --processes (default no-parallel,auto,parallel)")
    ap.add_argument("--cores", default="one,two", help="--processes: the set-ups, of one (taskset -c 0), two")
    ap.add_argument("--log", default="kitti", choices=sorted(LOGS), help="--processes: the log (default kitti)")
    ap.add_argument("--no-peer", action="store_true", help="--processes: without ORB-SLAM3")
    ap.add_argument("--peer", type=Path, default=PEER, help=f"the ORB-SLAM3 peer folder (default {PEER})")
    ap.add_argument("--build", type=Path, default=None, help="the peer's build folder (default /tmp/peer-orbslam3)")
    ap.add_argument("--sample", type=float, default=0.0, metavar="SECONDS",
                    help="sample the kernels on the first core at a low duty for SECONDS (see sample_mode)")
    ap.add_argument("--duty", type=float, default=0.125, help="--sample: the fraction of the time spent sampling")
    ap.add_argument("--out", default=None, help="--sample: write the samples (JSON) here")
    ap.add_argument("--toggle", action="store_true", help="the second core on and off every half second (see toggle_mode)")
    ap.add_argument("--realtime", action="store_true",
                    help="--toggle: both processes at real-time priority (chrt -f 10: each holds its core, "
                         "the other jobs wait), the off halves on a register-only loop instead of a sleep; "
                         "--processes: the programs at real-time priority")
    ap.add_argument("--partner", default=None, help="--toggle: the kernel on the second core (default: the same)")
    ap.add_argument("--role", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        if a.role:
            toggle_child(a.child, a.seconds, a.role)
        else:
            child(a.child, a.seconds)
        return 0
    bad = [k for k in [*a.kernels.split(","), a.partner or "warp"] if k.strip() and k.strip() not in KERNELS]
    if bad:
        print(f"core_contention: error: unknown kernel {bad[0]!r} (use {', '.join(KERNELS)})", file=sys.stderr)
        return 2
    if a.rounds < 1 or a.seconds <= 0:
        print("core_contention: error: --rounds must be >= 1 and --seconds > 0", file=sys.stderr)
        return 2
    if a.toggle:
        return toggle_mode(a)
    if a.sample > 0:
        return sample_mode(a)
    return processes_mode(a) if a.processes else kernels_mode(a)


if __name__ == "__main__":
    sys.exit(main())
