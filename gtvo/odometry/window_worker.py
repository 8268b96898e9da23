"""The window beside the tracker: a :class:`gtvo.odometry.window_link.WindowLink` in a worker
process, one of the two machines behind :class:`gtvo.odometry.window_port.WindowPort`.

``window.parallel: true``, or ``auto`` once the schedule moves the window here (docs/window.md,
"The window beside the tracker"). The window's host factors hold the GIL, so a thread would not
run them beside the tracker: the window lives in a worker process that owns its whole state
(keyframes with their images, the marginal prior, the rig offset, its copies of the window's
sensors: the wheel calibration, the IMU; with ``--refine`` the keyframes that left, handed back by
:meth:`WindowWorker.finish`). It starts from a :class:`gtvo.odometry.window_link.WindowLink` the
front end gives it, new or with the state a window in this process reached (``window.parallel:
auto``). On Linux (:data:`START_METHOD` ``"fork"``) the worker is a fork of the front end's
process: the link, the modules and the compiled kernels are already there, and the hand-over
costs milliseconds of CPU (a new interpreter spent 1.5-2 s of CPU importing gtvo, unpickling the
window, building its gradients again and loading the kernels: 20-25 % of a sequential run of
KITTI_sequence_1, and the front end waited for it at its first reply). Elsewhere (``"spawn"``: a
``python -c`` on a socket pair) the link is pickled whole (its images as grey levels, the
gradients built again bit for bit in the worker) into an anonymous file the worker reads once it
is up (the front end does not wait for its start). Either way whatever sensor the window has goes
with it, and each update the worker hands out carries every sensor's
:meth:`~gtvo.odometry.window_link.CarriedSensor.window_state` back to the front end's copy. The front end sends each new
keyframe (pose, points, the keyframe it was tracked against) with its two images in grey levels
through shared memory (a ring of :data:`SLOTS`
buffers in one ``memfd`` mapped by both: nothing to unlink, nothing for a resource tracker to
report), and gets back per keyframe one reply: the :class:`gtvo.odometry.window_link.WindowUpdate`
of the optimisation it asked for (poses, depths, figures), or nothing.

**The determinism rule.** The front end applies the reply for its ``n``-th keyframe right after
it has sent keyframe ``n + LAG`` (:data:`LAG` = 2), waiting for it if the worker is not done, and
every reply at :meth:`WindowWorker.finish`; a keyframe whose own stereo depths the next frames
should not track against (:meth:`gtvo.odometry.window_schedule.WindowSchedule.may_go_unrefined`)
waits for its reply at once. The worker handles its messages in order and its
replies depend on nothing else, so what the front end knows at every point of the sequence does
not depend on timing or load: two runs give byte-identical trajectories.

**Kernel threads.** The worker runs :func:`gtvo.core.kernel_threads.set_kernel_threads` with
``window.worker_threads`` (default :data:`DEFAULT_WORKER_THREADS`): its LM passes compute every
host's residuals at once on them (:func:`factors.smart.shared_residual_passes`), the same numbers
as one thread (docs/window.md, "Kernel threads in the worker").

**Clean ends.** The worker ignores SIGINT (the parent ends the run with its one line) and ends
when its pipe closes: when the parent closes it (:meth:`WindowWorker.close`), exits or dies. An
exception in the worker comes back as the same exception, raised by the front end at its next
reply; a worker that died (killed) is one :class:`WindowWorkerError`.
"""

from __future__ import annotations

import copyreg
import gc
import io
import mmap
import os
import pickle
import resource
import signal
import socket
import subprocess
import sys
import time
import traceback
import weakref
import dataclasses
from collections import deque
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from typing import Any, Callable, TypeVar

import numpy as np
from numpy.typing import NDArray

from factors.compact_image import compact_image
from factors.photometric import GradientImage
from gtvo.config import OdometryConfig
from gtvo.core.camera import PinholeCamera, StereoCamera
from gtvo.core.interrupt import interrupts_held
from gtvo.core.kernel_threads import kernel_threads, pool_cpu_seconds, set_kernel_threads
from gtvo.core.timing import StageClock, stage
from gtvo.odometry.blas import single_threaded_blas
from gtvo.odometry.window_link import KeyframeForWindow, WindowLink, WindowMember, WindowUpdate
from gtvo.window.fixed_lag import FixedLagBackend
from gtvo.window.optimizer import LMBackend
from gtvo.window import SlidingWindowOptimizer, WindowKeyframe, WindowResult
from gtvo.window.imu import ImuWindow
from gtvo.window.rig import RigOffset
from gtvo.window.wheel import WheelCalibration

T = TypeVar("T")

#: The front end applies the reply for keyframe ``n`` once it has sent keyframe ``n + LAG``.
LAG = 2
#: Shared image buffers: keyframe ``n`` uses slot ``n % SLOTS``, free once keyframe ``n - SLOTS``'s reply is in.
SLOTS = LAG + 1
#: The worker's kernel threads when ``window.worker_threads`` is unset: one (a second gave no
#: frames/s on the idle machine, docs/window.md, "Kernel threads in the worker").
DEFAULT_WORKER_THREADS = 1
#: The worker's stage clock's timer (wall time; a forked worker takes this process's value, so a
#: benchmark may set ``time.process_time`` for CPU seconds by stage: benchmarks/window_timeline.py).
STAGE_TIMER = time.perf_counter
#: How the worker starts: ``"fork"`` (a copy of the front end's process, Linux) or ``"spawn"`` (a new
#: interpreter that imports gtvo and unpickles the window: elsewhere).
START_METHOD = "fork" if sys.platform.startswith("linux") and hasattr(os, "fork") else "spawn"


class WindowWorkerError(RuntimeError):
    """The window's worker process ended without an answer (killed, or out of memory)."""


@dataclass
class WorkerUsage:
    """The worker's own figures: CPU seconds (user + system, all its threads), peak resident memory
    (MiB), wall seconds by stage of its :class:`gtvo.core.timing.StageClock`, its kernel threads
    and the CPU seconds its pool threads spent (:func:`gtvo.core.kernel_threads.pool_cpu_seconds`:
    the part of ``cpu_seconds`` that ran beside its main thread)."""

    cpu_seconds: float
    max_rss_mib: float
    seconds_by_stage: dict[str, float]
    kernel_threads: int = 1
    pool_cpu_seconds: float = 0.0


@dataclass
class MessageSpan:
    """One message the worker handled (or its start, ``kind`` ``"start"``: from the process's
    start to its first message): wall clock (``time.perf_counter``, system-wide) at its start and
    end, and the worker's CPU seconds (all threads) in between."""

    kind: str
    wall_start: float
    wall_end: float
    cpu_seconds: float


@dataclass
class FrontEndEvent:
    """What the front end did with the worker: ``"send"`` (message ``number`` sent) or ``"wait"``
    (for the reply of message ``number``: wall clock before and after), with the front end's
    process CPU seconds (``time.process_time``) at the event's start, the pickled bytes it sent
    (a send) or received (a wait: every reply that came in it), and the CPU seconds it took
    (pickling and writing; waiting, reading and unpickling)."""

    kind: str
    number: int
    wall_start: float
    wall_end: float
    cpu: float
    nbytes: int = 0
    cpu_seconds: float = 0.0


class WindowWorker:
    """The window in a worker process (module docstring): a
    :class:`gtvo.odometry.window_port.WindowPort` whose state is the window's as of the last
    update handed out (its members, their covariances, the rig offset, the wheel calibration, the
    results), and, after :meth:`finish` with ``retain_keyframes``, every keyframe it has had.

    Args:
        camera: a :class:`StereoCamera` for stereo input, a :class:`PinholeCamera` for RGB-D.
        config: the run's settings (``config.window.parallel``).
        wheel: the wheel calibration the window estimates (LM back end), or None.
        imu: the IMU's owner in the window (:class:`gtvo.window.imu.ImuWindow`), or None.
        link: the window to continue, with the state it reached in this process (its sensors are
            the front end's; ``wheel`` and ``imu`` are then unused); None: a new window with
            ``wheel`` and ``imu``. The worker estimates its own copies of the window's sensors;
            those of the front end take each handed-out update's state
            (:class:`gtvo.odometry.window_link.CarriedSensor`).
    """

    def __init__(self, camera: StereoCamera | PinholeCamera, config: OdometryConfig,
                 wheel: WheelCalibration | None = None, imu: ImuWindow | None = None,
                 link: WindowLink | None = None) -> None:
        pinhole = camera.left if isinstance(camera, StereoCamera) else camera
        self.config = config
        if link is None:
            link = WindowLink(camera, config, wheel=wheel, imu=imu)
        window = link.window
        self.backend = FixedLagBackend if config.window.backend == "fixed_lag" else LMBackend
        #: the window's keyframes after the last update handed out, oldest first
        self.members: list[WindowMember] = [
            WindowMember(w.index, w.pose, w.inverse_depth.copy(), None if w.right is None else w.stereo_affine.copy())
            for w in window.keyframes]
        #: frame index -> 6x6 pose covariance (as :attr:`SlidingWindowOptimizer.covariances`)
        self.covariances: dict[int, NDArray[np.float64]] = dict(window.covariances)
        self.results: list[WindowResult] = list(window.results)
        #: the window's sensors (the front end's objects), each as of the last update handed out
        self.sensors = window.sensors
        #: the wheel calibration (the front end's object), its estimate as of the last update handed out
        self.wheel = window.wheel
        #: the worker's window keeps every keyframe for the whole-log refinement (``refine.enabled``)
        self.retain_keyframes = bool(config.refine.enabled)
        self._every: list[WindowKeyframe] | None = None  # every keyframe, brought back by finish()
        stereo = isinstance(camera, StereoCamera)
        #: the worker's rig offset as of the last applied update (the front end's stereo search reads it)
        self.rig: RigOffset | None = window.rig
        self._rig_sent = self.rig is None or self.rig.initial is not None  # the worker's link has it
        self._sent = 0  # messages sent
        self._received: deque[Any] = deque()  # replies received, not yet handed out, in order
        self._n_received = 0
        self._joins: deque[int] = deque()  # per keyframe sent whose reply is not handed out: its message number
        #: the front end's sends and waits (:class:`FrontEndEvent`), for the timeline (benchmarks/parallel_window.py)
        self.events: list[FrontEndEvent] = []
        #: wall clock and this process's CPU seconds when the worker was asked for
        self.started = (time.perf_counter(), time.process_time())
        self._shape = (int(pinhole.height), int(pinhole.width))
        planes = 2 if stereo else 1
        self._slot_size = planes * self._shape[0] * self._shape[1] * 4
        self._memory, memory_fd = _shared_memory(SLOTS * self._slot_size)
        if START_METHOD == "fork":
            self._process, self._conn = _forked_worker(link, camera, config, self._memory, self._shape,
                                                       self._slot_size)
            os.close(memory_fd)
        else:
            self._process, self._conn = _spawned_worker(link, camera, config, memory_fd, self._shape,
                                                        self._slot_size)
        self._finalizer = weakref.finalize(self, _stop, self._conn, self._process, self._memory)

    # -- the port: driving the window ---------------------------------------------------------
    @property
    def backend_name(self) -> str:
        """The worker's window back end, ``"lm"`` or ``"fixed_lag"``."""
        return str(self.backend.name)

    def join(self, request: KeyframeForWindow, optimize: bool) -> None:
        """Send a new keyframe (and whether the window is optimised after it joins)."""
        self._every = None
        slot = self._sent % SLOTS
        self._receive_until(self._sent - SLOTS)  # the slot's last keyframe was read
        left = request.left.image if isinstance(request.left, GradientImage) else request.left
        images = [left] if request.right is None else [left, request.right]
        shared = all(np.shape(im) == self._shape for im in images)
        if shared:
            buf = _slot(self._memory, slot, self._slot_size, self._shape)
            for k, im in enumerate(images):
                buf[k] = im
            request = _without_images(request)
        else:  # an image of another size than the camera's: sent through the pipe
            request = _without_images(request, left=np.asarray(left, np.float32), right=request.right)
        rig = None
        if self.rig is not None and not self._rig_sent and self.rig.initial is not None:
            rig, self._rig_sent = self.rig, True
        self._send(("join", request, slot if shared else None, optimize, rig))
        self._joins.append(self._sent - 1)

    def optimize(self) -> None:
        """Ask for an optimisation of the window as it is (its reply comes with :meth:`finish`)."""
        self._send(("optimize",))
        self._joins.append(self._sent - 1)

    def due(self, now: bool = False) -> list[WindowUpdate]:
        """The updates the front end applies now, oldest first (waits for them): those of the
        keyframes joined :data:`LAG` or more keyframes ago, or with ``now`` every one."""
        return self._hand_out(len(self._joins) - (0 if now else LAG))

    def finish(self) -> list[WindowUpdate]:
        """The run's end: every update not handed out yet (waits for all); with ``retain_keyframes``
        also brings back every keyframe the worker's window has had (:meth:`every_keyframe`)."""
        updates = self.due(now=True)
        if self.retain_keyframes:
            self._every = self._ask(("every_keyframe",))
        return updates

    # -- the port: the window's state ----------------------------------------------------------
    def keyframe_indices(self) -> list[int]:
        """The frame indices of the window's keyframes as of the last update handed out."""
        return [m.index for m in self.members]

    def right_brightness(self) -> tuple[float, float] | None:
        """The newest member's right-camera brightness ``(a, b)`` as of the last update handed out."""
        last = self.members[-1].stereo_affine if self.members else None
        return None if last is None else (float(last[0]), float(last[1]))

    def rig_offset_covariance(self) -> NDArray[np.float64] | None:
        """:meth:`gtvo.window.SlidingWindowOptimizer.rig_offset_covariance` of the worker's window now."""
        return self._ask(("rig_offset_covariance",))

    def wheel_covariance(self) -> NDArray[np.float64] | None:
        """:meth:`gtvo.window.SlidingWindowOptimizer.wheel_covariance` of the worker's window now,
        also kept in the front end's ``wheel.covariance``."""
        if self.wheel is None:
            return None
        cov = self._ask(("wheel_covariance",))
        if cov is not None:
            self.wheel.covariance = cov
        return cov

    def every_keyframe(self) -> list[WindowKeyframe]:
        """Every keyframe the worker's window has had (``retain_keyframes``), oldest first, their
        images compact (:mod:`factors.compact_image`), as of the last :meth:`finish` (asked now
        when a keyframe joined since and the worker still runs)."""
        if self._every is None:
            self._every = self._ask(("every_keyframe",))
        return self._every

    def inspect(self, probe: Callable[[SlidingWindowOptimizer], T]) -> T:
        """``probe`` (a module-level function: it is pickled) on the worker's window as it is now."""
        return self._ask(("inspect", probe))

    def on_second_core(self) -> WindowWorker:
        """This window (it runs on the second core already)."""
        return self

    def timeline(self) -> list[MessageSpan]:
        """The worker's spans so far: its start, then one per message handled, in order."""
        return self._ask(("timeline",))

    def worker_usage(self) -> WorkerUsage:
        """The worker's CPU time, peak memory and stage seconds so far."""
        return self._ask(("usage",))

    def solver_name(self, requested: str) -> str:
        """The solver the worker's window runs for ``requested`` (:meth:`SlidingWindowOptimizer.solver_name`)."""
        return "gtsam_isam2" if self.backend is FixedLagBackend else str(requested)

    @property
    def pid(self) -> int:
        """The worker's process id."""
        return self._process.pid

    def close(self) -> None:
        """End the worker (closing its pipe; it exits at its next message); idempotent."""
        self._finalizer()

    # -- the pipe ------------------------------------------------------------------------------
    def _send(self, message: tuple) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        data = ForkingPickler.dumps(message)  # as Connection.send pickles it, its size counted
        try:
            self._conn.send_bytes(data)
        except (BrokenPipeError, EOFError, OSError):
            raise self._died() from None
        self.events.append(FrontEndEvent("send", self._sent, wall, time.perf_counter(), cpu, len(data),
                                         time.process_time() - cpu))
        self._sent += 1

    def _hand_out(self, count: int) -> list[WindowUpdate]:
        out = []
        for _ in range(max(count, 0)):
            number = self._joins.popleft()
            self._receive_until(number)
            reply = self._received.popleft()
            if reply is not None:
                self._take(reply)
                out.append(reply)
        return out

    def _take(self, update: WindowUpdate) -> None:
        """The port's state as of ``update`` (handed out now)."""
        self.members = update.members
        self.rig = update.rig
        self.results.append(update.result)
        if update.result.covariances is not None:
            self.covariances.update(update.result.covariances)
        for sensor, state in zip(self.sensors, update.sensor_states or ()):
            sensor.take_window_state(state)

    def _ask(self, message: tuple) -> Any:
        self._send(message)
        number = self._sent - 1
        self._receive_until(number)
        # the replies of earlier messages stay queued in front (in order); this one is the last
        return self._received.pop()

    def _receive_until(self, number: int) -> None:
        """Receive replies until that of message ``number`` is in (the front end waits here)."""
        if self._n_received > number:
            return
        wall, cpu = time.perf_counter(), time.process_time()
        nbytes = 0
        with stage("window_wait"):
            while self._n_received <= number:
                try:
                    data = self._conn.recv_bytes()
                except (EOFError, OSError):
                    raise self._died() from None
                nbytes += len(data)
                kind, value = ForkingPickler.loads(data)  # as Connection.recv unpickles it
                self._n_received += 1
                if kind == "error":
                    self.close()
                    raise value
                self._received.append(value)
        self.events.append(FrontEndEvent("wait", number, wall, time.perf_counter(), cpu, nbytes,
                                         time.process_time() - cpu))

    def _died(self) -> WindowWorkerError:
        try:
            code: int | None = self._process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            code = None
        self.close()
        return WindowWorkerError(f"the window's worker process ended unexpectedly (exit code {code}): "
                                 "killed, or out of memory; run with --no-parallel to keep the window in one process")


def _spawned_worker(link: WindowLink, camera: StereoCamera | PinholeCamera, config: OdometryConfig, memory_fd: int,
                    shape: tuple[int, int], slot_size: int) -> tuple[subprocess.Popen, Connection]:
    """A new interpreter (``python -c`` on a socket pair) that imports gtvo, reads ``link`` pickled
    (:func:`window_bytes`) from an anonymous file once it is up, loads the compiled kernels and
    serves: the start method where ``os.fork`` is not safe to use (not Linux)."""
    state_fd = _state_file(window_bytes(link))  # read by the worker when it is up: the front end goes on
    parent_sock, child_sock = socket.socketpair()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if isinstance(p, str)))
    with interrupts_held():  # the worker starts with SIGINT blocked, then ignores it
        process = subprocess.Popen(
            [sys.executable, "-c", _WORKER_MAIN, str(child_sock.fileno()), str(memory_fd), str(state_fd)],
            pass_fds=(child_sock.fileno(), memory_fd, state_fd), stdin=subprocess.DEVNULL, env=env,
            close_fds=True)
    child_sock.close()
    os.close(memory_fd)
    os.close(state_fd)
    conn = Connection(os.dup(parent_sock.fileno()))
    parent_sock.close()
    try:  # the worker's settings: the one message without a reply (its window is in its state file)
        conn.send(("start", camera, config, shape, SLOTS, slot_size))
    except OSError:
        process.wait()
        raise WindowWorkerError("the window's worker process did not start") from None
    return process, conn


def _forked_worker(link: WindowLink, camera: StereoCamera | PinholeCamera, config: OdometryConfig,
                   memory: mmap.mmap, shape: tuple[int, int], slot_size: int) -> tuple[ForkedProcess, Connection]:
    """A copy of this process (``os.fork``) that serves ``link`` as it is here: nothing imported,
    pickled or built again (its modules, compiled kernels and the window's images are this
    process's pages, copied by the kernel only where one side writes), so the hand-over costs
    milliseconds instead of the second or two of CPU a new interpreter takes. The child closes
    every descriptor but its end of the pipe (a pipe of this process's other workers it held would
    keep them from seeing their end), freezes the objects it inherited (the cyclic collector leaves
    them, and their finalizers, to this process), opens its own standard streams and never returns:
    it ends with ``os._exit``."""
    parent_sock, child_sock = socket.socketpair()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()  # nothing buffered here is written twice
        except (AttributeError, OSError, ValueError):
            pass
    with interrupts_held():  # the child starts with SIGINT blocked, then ignores it
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child (covered by the parallel window's tests)
            code = 1
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
                keep = child_sock.fileno()
                os.closerange(3, keep)
                os.closerange(keep + 1, _max_fd())
                gc.freeze()
                # its own standard streams: a lock another thread of this process held at the fork
                # (a progress bar writing) stays held in the child's copies
                sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
                sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
                wall0, cpu0 = time.perf_counter(), time.process_time()
                conn = Connection(keep)
                set_kernel_threads(worker_threads(config))
                with single_threaded_blas():
                    if not link.window.keyframes:  # a new window: its kernels loaded before the first keyframe
                        warm_up(camera, config)
                start = MessageSpan("start", wall0, time.perf_counter(), time.process_time() - cpu0)
                serve(conn, link, memory, slot_size, shape, [start])
                code = 0
            finally:
                os._exit(code)
    child_sock.close()
    return ForkedProcess(pid), Connection(parent_sock.detach())


def _max_fd() -> int:
    """One more than the highest descriptor number this process may have open."""
    try:
        return max(int(name) for name in os.listdir("/proc/self/fd")) + 1
    except (OSError, ValueError):
        return int(os.sysconf("SC_OPEN_MAX"))


class ForkedProcess:
    """The forked worker, with the part of :class:`subprocess.Popen`'s interface the port uses."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        """The exit code (negative: the signal that ended it) once the process ended, else None."""
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere
                self.returncode = -1
                return self.returncode
            if pid != 0:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for the process to end (``subprocess.TimeoutExpired`` after ``timeout`` seconds)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        delay = 0.0005
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"window worker {self.pid}", timeout or 0.0)
            time.sleep(delay)
            delay = min(2 * delay, 0.05)
        assert self.returncode is not None
        return self.returncode

    def kill(self) -> None:
        """SIGKILL, unless it has ended."""
        if self.poll() is None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def window_bytes(link: WindowLink) -> bytes:
    """``link`` pickled for the worker, its full images (:class:`GradientImage`) as their grey
    levels: the worker builds their gradients again, bit for bit (the same compiled pass on the same
    float32 values), so the window's state crosses at a fifth of its size."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.dispatch_table = copyreg.dispatch_table.copy()
    pickler.dispatch_table[GradientImage] = _grey_levels_only
    pickler.dump(link)
    return buffer.getvalue()


def _grey_levels_only(image: GradientImage) -> tuple:
    """The pickle reduction of a :class:`GradientImage` to its constructor's arguments (exact type
    only: a compact image keeps its own)."""
    return GradientImage, (image.image, image.border, image.clip_range)


def _without_images(request: KeyframeForWindow, left: Any = None, right: Any = None) -> KeyframeForWindow:
    """The request with its images replaced (None: they travel through shared memory)."""
    from dataclasses import replace  # noqa: PLC0415

    return replace(request, left=left, right=right)


def _stop(conn: Connection, process: subprocess.Popen, memory: mmap.mmap) -> None:
    """Close the worker's pipe (it exits at once when idle, else after its current optimisation)."""
    try:
        conn.close()
    except OSError:
        pass
    try:
        process.wait(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=5)
    try:
        memory.close()
    except BufferError:  # an array still views it: the mapping goes with the process
        pass


def _shared_memory(size: int) -> tuple[mmap.mmap, int]:
    """An anonymous shared mapping of ``size`` bytes and its file descriptor (for the worker)."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("gtvo-window", os.MFD_CLOEXEC)
    else:  # pragma: no cover - not Linux: an unlinked temporary file
        import tempfile  # noqa: PLC0415

        with tempfile.TemporaryFile() as f:
            fd = os.dup(f.fileno())
    os.ftruncate(fd, size)
    return mmap.mmap(fd, size), fd


def _state_file(data: bytes) -> int:
    """An anonymous file holding ``data`` (the worker's starting window), its descriptor for the worker."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("gtvo-window-state", os.MFD_CLOEXEC)
    else:  # pragma: no cover - not Linux: an unlinked temporary file
        import tempfile  # noqa: PLC0415

        with tempfile.TemporaryFile() as f:
            fd = os.dup(f.fileno())
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]
    return fd


def _slot(memory: mmap.mmap, slot: int, slot_size: int, shape: tuple[int, int]) -> NDArray[np.float32]:
    """The images of shared slot ``slot`` as a (planes, H, W) float32 view."""
    return np.frombuffer(memory, dtype=np.float32, count=slot_size // 4, offset=slot * slot_size).reshape(-1, *shape)


#: The worker's ``python -c`` program: SIGINT ignored before anything is imported (the parent ends
#: the run; this process follows its pipe), then :func:`serve` on the descriptors it was given.
_WORKER_MAIN = ("import signal, sys; signal.signal(signal.SIGINT, signal.SIG_IGN); "
                "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT}); "
                "from gtvo.odometry.window_worker import main; main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))")


def main(socket_fd: int, memory_fd: int, state_fd: int) -> None:
    """The worker process: its pipe, shared memory and starting window (``state_fd``: the pickled
    :class:`gtvo.odometry.window_link.WindowLink`, :func:`window_bytes`) from the parent, then :func:`serve`."""
    wall0 = time.perf_counter()
    conn = Connection(socket_fd)
    with os.fdopen(state_fd, "rb") as state:
        state.seek(0)
        link: WindowLink = pickle.load(state)
    try:
        kind, camera, config, shape, slots, slot_size = conn.recv()
    except (EOFError, OSError):
        return
    memory = mmap.mmap(memory_fd, slots * slot_size)
    set_kernel_threads(worker_threads(config))
    with single_threaded_blas():
        warm_up(camera, config)
    ru = resource.getrusage(resource.RUSAGE_SELF)
    start = MessageSpan("start", wall0, time.perf_counter(), ru.ru_utime + ru.ru_stime)
    serve(conn, link, memory, slot_size, shape, [start])


def worker_threads(config: OdometryConfig) -> int:
    """The worker's kernel threads: ``window.worker_threads``, :data:`DEFAULT_WORKER_THREADS` when unset."""
    threads = config.window.worker_threads
    return DEFAULT_WORKER_THREADS if threads is None else int(threads)


def warm_up(camera: StereoCamera | PinholeCamera, config: OdometryConfig) -> None:
    """Load the window's compiled kernels (numba's disk cache: about half a second of CPU) before
    the first keyframe comes: one optimisation of a window of two small textured keyframes of this
    camera's kind. Best effort: a failure here only leaves the loading to the first keyframe."""
    import gtsam  # noqa: PLC0415

    from gtvo.frontend import KeyframePoints  # noqa: PLC0415

    rng = np.random.default_rng(0)
    small = PinholeCamera(60.0, 60.0, 32.0, 24.0, 64, 48)
    cam: StereoCamera | PinholeCamera = small
    if isinstance(camera, StereoCamera):
        cam = dataclasses.replace(camera, left=small)
    texture = (128 + 60 * np.sin(np.arange(64)[None, :] / 3.0) * np.cos(np.arange(48)[:, None] / 4.0)).astype(np.float32)
    grid = np.stack(np.meshgrid(np.arange(8, 56, 4.0), np.arange(8, 40, 4.0)), -1).reshape(-1, 2)
    points = KeyframePoints(grid, np.full(len(grid), 0.5), np.full(len(grid), 1e-3), np.full(len(grid), 128.0))
    try:
        link = WindowLink(cam, dataclasses.replace(config, window=dataclasses.replace(config.window, parallel=False)))
        for k in range(2):
            noise = rng.normal(0, 1, texture.shape).astype(np.float32)
            right = np.roll(texture, -3, axis=1) + noise if isinstance(camera, StereoCamera) else None
            link.join(KeyframeForWindow(k, 0.1 * k, gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 0.05 * k])),
                                        points, (k - 1, np.zeros(2)) if k else None, texture + noise, right))
        link.optimize()
    except Exception:  # noqa: BLE001,S110 - best effort (module docstring)
        pass


def serve(conn: Connection, link: WindowLink, memory: mmap.mmap, slot_size: int, shape: tuple[int, int],
          timeline: list[MessageSpan] | None = None) -> None:
    """The worker's loop on its window ``link`` (with the worker's copies of its sensors): one reply
    per message, in order, until the pipe closes. ``timeline``: the worker's spans so far (its
    start), each message's appended (:class:`MessageSpan`, read with the ``timeline`` message)."""
    clock = StageClock(timer=STAGE_TIMER)
    spans: list[MessageSpan] = [] if timeline is None else timeline
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        wall0, cpu0 = time.perf_counter(), time.process_time()
        try:
            if message[0] == "timeline":
                reply: Any = list(spans)
            else:
                with clock.activate("other"), single_threaded_blas():
                    reply = _handle(link, message, memory, slot_size, shape, clock)
        except BaseException as exc:  # noqa: BLE001 - every failure goes back to the front end
            try:
                conn.send(("error", _portable(exc)))
            except (BrokenPipeError, EOFError, OSError):
                return
            continue
        try:
            conn.send(("ok", reply))
        except (BrokenPipeError, EOFError, OSError):
            return
        spans.append(MessageSpan(str(message[0]), wall0, time.perf_counter(), time.process_time() - cpu0))


def _handle(link: WindowLink, message: tuple, memory: mmap.mmap, slot_size: int, shape: tuple[int, int],
            clock: StageClock) -> Any:
    kind = message[0]
    if kind == "join":
        _, request, slot, optimize, rig = message
        if rig is not None:
            link.window.rig = rig
        if slot is not None:
            buf = _slot(memory, slot, slot_size, shape)
            stereo = isinstance(link.camera, StereoCamera)
            request.left = buf[0].copy()
            request.right = buf[1].copy() if stereo else None
        link.join(request)
        return _with_sensor_states(link, link.optimize()) if optimize else None
    if kind == "optimize":
        return _with_sensor_states(link, link.optimize())
    if kind == "inspect":
        return message[1](link.window)
    if kind == "rig_offset_covariance":
        return link.window.rig_offset_covariance()
    if kind == "wheel_covariance":
        return link.window.wheel_covariance()
    if kind == "every_keyframe":  # images compact: grey levels only (factors.compact_image)
        return [dataclasses.replace(k, image=compact_image(k.image), right=compact_image(k.right))
                for k in link.window.every_keyframe()]
    if kind == "usage":
        ru = resource.getrusage(resource.RUSAGE_SELF)
        return WorkerUsage(ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0, clock.snapshot(), kernel_threads(),
                           pool_cpu_seconds())
    raise ValueError(f"unknown window worker message {kind!r}")


def _with_sensor_states(link: WindowLink, update: WindowUpdate | None) -> WindowUpdate | None:
    """``update`` with what the front end reads of each of the window's sensors now."""
    if update is not None:
        indices = [w.index for w in link.window.keyframes]
        update.sensor_states = [sensor.window_state(indices) for sensor in link.window.sensors]
    return update


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its type, message and traceback."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001
        text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
        return RuntimeError(f"in the window's worker process: {text}")
