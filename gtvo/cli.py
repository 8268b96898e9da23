"""The ``gtvo`` command line: a thin shell over the library.

Each subcommand lives in its own module under :mod:`gtvo.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``.
Bad input (:class:`gtvo.errors.InputError`) becomes one line on stderr and exit code 2; so does
an operating-system error (``OSError``: an output the system refuses to write). Ctrl-C anywhere
becomes ``gtvo CMD: interrupted`` and exit code 130 (also when compiled code it stopped reports
it as another error: :func:`caused_by_interrupt`), until the command's outputs are in place
(:func:`gtvo.core.interrupt.outputs_in_place`): then it has succeeded. A closed stdout pipe
(``gtvo ... | head``) is exit code 0, without a word.
"""

from __future__ import annotations

import argparse
import atexit
import importlib
import os
import signal
import sys
import threading
import warnings

# gtvo's linear algebra is many small products (8x8 .. 6000x16); multithreaded BLAS on a busy
# 2-core machine made them up to 300x slower (docs/benchmarks.md, sliding window). The CLI runs
# BLAS single-threaded unless the user says otherwise; set before numpy is first imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
from typing import Any, Callable, Sequence

from gtvo import __version__
from gtvo.core.interrupt import interrupt_requested, note_interrupt, raise_if_interrupted
from gtvo.core.atomic import tidy_on_failure
from gtvo.errors import DependencyError, InputError, TrackingFailure, caused_by_interrupt

# One module per subcommand, in the order `gtvo --help` lists them.
COMMAND_MODULES: tuple[str, ...] = (
    "gtvo.commands.demo",
    "gtvo.commands.run",
    "gtvo.commands.info",
    "gtvo.commands.batch",
    "gtvo.commands.synthetic",
    "gtvo.commands.plan",
    "gtvo.commands.calibrate_odometry",
    "gtvo.commands.loops",
    "gtvo.commands.posegraph",
)


def command_module(name: str) -> str | None:
    """The module of the subcommand ``name`` (``calibrate-odometry``: ``gtvo.commands.calibrate_odometry``),
    None when no subcommand has that name."""
    for module in COMMAND_MODULES:
        if module.rsplit(".", 1)[1].replace("_", "-") == name:
            return module
    return None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered, or only the subcommand ``command``.

    A command module imports what its parser needs (``gtvo run``'s: the readers); registering only
    the command that is run (:func:`_run`) leaves the others' imports out of its start-up time. The
    one command's parser, its help and its errors are the same as with all registered.
    """
    only = command_module(command) if command is not None else None
    parser = argparse.ArgumentParser(
        prog="gtvo",
        description="Direct stereo visual odometry on GTSAM: sliding-window optimisation of logged tracks.",
    )
    parser.add_argument("--version", action="version", version=f"gtvo {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES if only is None else (only,):
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``gtvo`` command line ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    The SIGINT handler is as it was when the command returns (a command ignores Ctrl-C once its
    outputs are in place: :func:`gtvo.core.interrupt.outputs_in_place`).
    """
    handler = signal.getsignal(signal.SIGINT)
    try:
        return _main(argv)
    finally:
        if handler is not None and signal.getsignal(signal.SIGINT) is not handler \
                and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, handler)


def _main(argv: Sequence[str] | None = None) -> int:
    """:func:`main` without the SIGINT handler put back (:func:`entry_point` ignores Ctrl-C after it).

    ``gtvo ... | head``: when the reader of stdout leaves, gtvo stops quietly with exit code 0, not
    with an error line: a closed pipe is the reader's choice, not a failure (stdout is pointed at
    ``os.devnull``, as Python's documentation of ``BrokenPipeError`` recommends, so that the
    interpreter's last flush does not fail again).
    """
    try:
        try:
            code = _run(argv)
        except SystemExit:  # argparse after --help or a usage error
            sys.stdout.flush()
            raise
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except BrokenPipeError:
        _silence_stdout()
        return 0


def _run(argv: Sequence[str] | None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    try:
        # `gtvo CMD ...` builds only CMD's parser (start-up time); `gtvo`, `gtvo --help`, a bad name: all of them
        args = build_parser(words[0] if words else None).parse_args(words)
    except KeyboardInterrupt:  # while the command modules are imported
        words = [a for a in words if not a.startswith("-")]
        known = {m.rsplit(".", 1)[1].replace("_", "-") for m in COMMAND_MODULES}
        name = f"gtvo {words[0]}" if words and words[0] in known else "gtvo"
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    try:
        try:
            with tidy_on_failure():  # a failed command leaves no empty output folder behind
                code = int(args.func(args) or 0)
            raise_if_interrupted()  # a Ctrl-C that a library swallowed (gtvo.core.interrupt)
            return code
        except BrokenPipeError:
            raise
        except Exception as exc:
            # e.g. a SystemError from compiled code that Ctrl-C stopped, or an error that followed a
            # Ctrl-C some library swallowed
            if caused_by_interrupt(exc) or interrupt_requested():
                raise KeyboardInterrupt from exc
            raise
    except BrokenPipeError:
        raise
    except (InputError, DependencyError) as exc:
        print(f"gtvo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # an output the system refuses (disk full, permissions) after the checks
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"gtvo {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except TrackingFailure as exc:
        print(f"gtvo {args.command}: tracking failed: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print(f"gtvo {args.command}: interrupted", file=sys.stderr)
        return 130


def entry_point() -> None:
    """The ``gtvo`` console script and ``python -m gtvo``: :func:`main`, then exit with its code.

    Once the command is done, Ctrl-C is ignored: the interpreter's shutdown (which would otherwise
    die of the signal without a word) can no longer change anything the command did.
    """
    signal.signal(signal.SIGINT, note_interrupt)
    sys.unraisablehook = _quiet_interrupts(sys.unraisablehook)
    # gtvo draws no 3-D axes; matplotlib warns about them only when a Ctrl-C broke its optional import
    warnings.filterwarnings("ignore", message="Unable to import Axes3D")
    code = _main()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if interrupt_requested() and code != 130:  # (none after the outputs were in place: outputs_in_place)
        code = 130
    if code == 130:
        # interrupted: leave now. The interpreter's finalisers run inside libraries the interrupt may
        # have left half-done and were measured to turn exit 130 into 1 or a SIGINT death (about 1 run
        # in 12 interrupted at random); the outputs are already whole or untouched (atomic writes).
        _release_process_resources()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(130)
    _exit_without_teardown(code)


def _exit_without_teardown(code: int) -> None:
    """End the process with ``code`` as the interpreter would, without its teardown of every module
    and object: as at the interpreter's exit the threads' exit hooks run and the other threads are
    joined (``threading._shutdown``), then the exit handlers (:mod:`atexit`: a process pool's,
    logging's); the standard streams are flushed, then :func:`os._exit`. The teardown does nothing a
    finished command needs (its outputs are written and closed) and was measured at 0.6-0.7 s of CPU
    after a ``gtvo run`` (the compiled kernels, GTSAM's and numba's objects): a third of the time a
    run spent after its last frame (docs/benchmarks.md)."""
    shutdown = getattr(threading, "_shutdown", None)  # what the interpreter's exit does first: the
    if shutdown is not None:  # threading exit hooks (thread pools' wake-up), then every other thread joined
        shutdown()
    else:  # pragma: no cover - an interpreter without it
        for thread in threading.enumerate():
            if thread is not threading.main_thread() and not thread.daemon:
                thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # noqa: PERF203 - a closed pipe or stream: nothing left to say there
            pass
    os._exit(code)


def _release_process_resources() -> None:
    """Unlink the named semaphores of process pools (``gtvo batch``'s) before the immediate exit of
    an interrupted command: the interpreter's exit, which it skips, would have done it (through
    multiprocessing's exit finalizers); else multiprocessing's resource tracker reports them as
    leaked on stderr after the command's one line."""
    util = sys.modules.get("multiprocessing.util")
    if util is None:
        return
    try:
        util._run_finalizers(0)  # the finalizers of priority >= 0: semaphores, queues (not the joins)
    except Exception:  # noqa: BLE001,S110 - on the way out: nothing left to report it to
        pass


def _quiet_interrupts(hook: Callable[[Any], None]) -> Callable[[Any], None]:
    """An unraisable-exception hook that drops a Ctrl-C raised where Python cannot propagate it (a
    weakref or ctypes callback: "Exception ignored in ..."): the interrupt is recorded anyway
    (:mod:`gtvo.core.interrupt`) and the command ends with its one line. Once a Ctrl-C was seen, it
    drops any unraisable exception: they are the finalisers of objects the interrupt left half-made
    inside a library (seen: llvmlite's ``ObjectRef.__del__`` when the Ctrl-C came while numba loaded a
    compiled kernel). Without an interrupt they are printed as before."""
    def hook_(unraisable: Any) -> None:
        if not isinstance(unraisable.exc_value, KeyboardInterrupt) and not interrupt_requested():
            hook(unraisable)
    return hook_


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so that the interpreter's last flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # no real file descriptor (e.g. captured output)
        pass


if __name__ == "__main__":  # pragma: no cover
    entry_point()
