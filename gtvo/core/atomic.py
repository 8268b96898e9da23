"""Atomic output: write to a temporary file in the same folder, then rename.

An interrupted run never leaves a half-written file behind, and an older file of the same
name stays intact until the new one is complete. :func:`atomic_dir` does the same for a whole
folder (a written sequence, a run's output set).
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
import json
import os
import re
import shutil
import signal
import tempfile
import threading
from pathlib import Path
from typing import IO, Any, Callable, Iterable, Iterator

from gtvo.core.paths import link_problem, resolved, same_or_inside
from gtvo.errors import InputError


#: Folders made by :func:`ensure_output_dir` inside the innermost :func:`tidy_on_failure` block.
_CREATED: contextvars.ContextVar[list[Path] | None] = contextvars.ContextVar("gtvo_created_dirs", default=None)


@contextlib.contextmanager
def tidy_on_failure() -> Iterator[None]:
    """Undo the folders :func:`ensure_output_dir` creates in this block if the block fails.

    Output folders are made before the long work, so that a bad ``--out`` is reported at once;
    when the work then fails (bad input found later, Ctrl-C), the folders this block made are
    removed again, deepest first, as long as they are still empty. Folders that existed before,
    and any folder something was written into, are left alone.
    """
    created: list[Path] = []
    token = _CREATED.set(created)
    try:
        yield
    except BaseException:
        for folder in reversed(created):
            try:
                folder.rmdir()
            except OSError:  # not empty (so are its parents), or already gone: leave it alone
                pass
        raise
    finally:
        _CREATED.reset(token)
        outer = _CREATED.get()
        if outer is not None:  # a nested block: the outer one answers for these folders too
            outer.extend(p for p in created if p.is_dir())


def ensure_output_dir(path: str | Path) -> Path:
    """Create the output folder ``path`` (and its parents) or raise a one-line :class:`InputError`.

    Called before long work, so that an unusable ``--out`` (a file, a folder under a file, no
    permission) is reported at once rather than after the run. Inside :func:`tidy_on_failure`
    the folders it creates are removed again if the work fails.
    """
    path = Path(path)
    problem = link_problem(path)
    if problem is not None:
        raise InputError(f"output folder is {problem}", path=path)
    if path.exists() and not path.is_dir():
        raise InputError("output folder is a file", path=path)
    missing = []
    probe = Path(os.path.abspath(path))  # '..' collapsed, so that an existing folder is not taken for new
    while not probe.exists() and probe != probe.parent:
        missing.append(probe)
        probe = probe.parent
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({exc.strerror or exc})", path=path) from None
    created = _CREATED.get()
    if created is not None:
        created.extend(reversed(missing))  # outermost first, so that undoing goes deepest first
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError("output folder is not writable", path=path)
    return path


def check_output_file(path: str | Path) -> Path:
    """Check that ``path`` can be written as a file (its folder is created): a one-line
    :class:`InputError` when it is a folder or its folder cannot be made."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder; expected a file name", path=path)
    ensure_output_dir(path.parent)
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` if the block succeeds.

    Use it for writers that want a file name (``cv2.imwrite``, ``open3d.io``, matplotlib).
    ``suffix`` defaults to the final suffix of ``path`` so that writers that pick the format
    from the extension keep working. An ``OSError`` of the block that names no file (or the
    temporary one) is raised again naming ``path``.
    """
    path = check_output_file(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp creates 0600 files; give the result the permissions a plain open() would.
    os.chmod(tmp_path, 0o666 & ~_umask())
    try:
        try:
            yield tmp_path
        except OSError as exc:  # (a full disk while writing): named by the file asked for, not the temporary one
            if exc.filename is None or str(exc.filename) == str(tmp_path):
                raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc
            raise
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "w", encoding: str | None = "utf-8") -> Iterator[IO[Any]]:
    """Open a temporary file for writing; it replaces ``path`` only when the block succeeds."""
    if "b" in mode:
        encoding = None
    with atomic_path(path) as tmp:
        with open(tmp, mode, encoding=encoding) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically."""
    with atomic_open(path, "w") as f:
        f.write(text)
    return Path(path)


def write_json(path: str | Path, obj: Any, indent: int = 2) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (NaN is refused: it is not JSON)."""
    text = json.dumps(obj, indent=indent, allow_nan=False, sort_keys=False)
    return write_text(path, text + "\n")


def write_with(path: str | Path, writer: Callable[[Path], Any]) -> Path:
    """Call ``writer(tmp_path)`` and rename the result onto ``path`` atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


#: The file by which :func:`atomic_dir` recognises a folder it wrote (and may therefore replace).
DIR_MARKER = ".gtvo-output"


@contextlib.contextmanager
def atomic_dir(path: str | Path, replaceable: frozenset[str] | set[str], writer: str) -> Iterator[Path]:
    """Yield a new temporary folder next to ``path``; when the block succeeds it becomes ``path``.

    For outputs that are a whole folder (a written sequence, a run's outputs): an interrupted
    write leaves the old folder as it was, and a shorter new set leaves no stale files of the old
    one. The swap is two renames (the old folder aside into a hidden ``.NAME.old.*`` folder, the
    new one in); Ctrl-C is held back between them (:func:`deferred_interrupts`), so only a crash
    of the machine there can leave the old folder aside. An existing ``path`` is replaced only when it is empty, or when it carries the
    :data:`DIR_MARKER` file that this function writes (``writer`` names who wrote it) and holds
    nothing but that and entries named in ``replaceable``. Anything else (a real dataset folder
    with the same layout, a folder with a user's files, the current folder or one above it)
    raises :class:`InputError` rather than deleting anything. The check is made again just
    before the replacement. A symbolic link is followed: its target is replaced.
    """
    path = check_replaceable_dir(path, replaceable, writer)
    parent = ensure_output_dir(path.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=parent))
    os.chmod(tmp, 0o777 & ~_umask())
    try:
        try:
            yield tmp
        except OSError as exc:  # (a full disk): named by where the file was going, not the staging folder
            inside = exc.filename is not None and Path(str(exc.filename)).is_relative_to(tmp)
            if not inside:
                raise
            raise OSError(exc.errno, exc.strerror or str(exc), str(path / Path(str(exc.filename)).relative_to(tmp))) \
                from exc
        (tmp / DIR_MARKER).write_text(f"written by {writer}; {path.name} may be replaced by it as a whole\n",
                                     encoding="utf-8")
        check_replaceable_dir(path, replaceable, writer)
        with deferred_interrupts():  # no Ctrl-C between the two renames: old set or new set, never neither
            _swap_in(tmp, path, parent)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def check_replaceable_dir(path: str | Path, replaceable: frozenset[str] | set[str], writer: str) -> Path:
    """The resolved ``path`` if :func:`atomic_dir` may replace it, else a one-line :class:`InputError`.

    It may when it does not exist, is empty, or carries :data:`DIR_MARKER` and holds nothing but
    that and entries named in ``replaceable``; never the current folder or one above it.
    """
    path = resolved(path, "output folder")
    if same_or_inside(Path.cwd(), path):
        raise InputError("output folder is the current folder or contains it; choose another", path=path)
    if not path.exists():
        return path
    if not path.is_dir():
        raise InputError("output folder is a file", path=path)
    names = {p.name for p in path.iterdir()}
    if not names:
        return path
    foreign = sorted(names - set(replaceable) - {DIR_MARKER})
    if DIR_MARKER not in names or foreign:
        listed = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        why = f"it holds other files ({listed})" if foreign else f"it was not written by {writer}"
        raise InputError(f"output folder is not empty and {why}; choose a new or empty folder", path=path)
    return path


#: The lock file of an output folder ``NAME``, beside it: ``.NAME.lock`` (a lock inside the folder
#: would go aside with the old set when :func:`atomic_dir` swaps the new one in).
LOCK_NAME = ".{name}.lock"


@contextlib.contextmanager
def output_lock(path: str | Path, file_names: Iterable[str] = ()) -> Iterator[Path]:
    """Hold the lock of the output folder ``path`` during the block; yields ``path`` resolved.

    One writer at a time: a second gtvo process that asks for the lock of the same folder
    (whatever its spelling: the lock file is found by the folder's real path, and a bind mount
    of the parent reaches the same file) gets a one-line :class:`InputError` at once, instead of
    both running and the later one silently replacing the earlier one's outputs. The lock is
    ``fcntl.flock`` on :data:`LOCK_NAME` beside the folder; the system releases it when the
    process ends in any way (killed too); the file is removed when the block ends.

    Holding the lock, it removes what an earlier writer that was killed left
    (:func:`discard_unfinished`: gtvo's own staging folders beside ``path``, a set put aside put
    back, the temporary files of ``file_names`` inside it): no writer can be busy with them.
    """
    path = resolved(path, "output folder")
    above = next(p for p in path.parents if p.exists() or p == p.parent)
    if not above.is_dir():
        raise InputError(f"cannot create the output folder ({above} is a file)", path=path)
    parent = ensure_output_dir(path.parent)
    lock = parent / LOCK_NAME.format(name=path.name)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666 & ~_umask())
        except OSError as exc:
            raise InputError(f"cannot create the output folder's lock file {lock.name} beside it "
                             f"({exc.strerror or exc})", path=path) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _lock_holder(fd)
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise InputError(f"cannot lock the output folder ({exc.strerror or exc})", path=path) from None
            raise InputError(f"another gtvo process{holder} is writing into this output folder (its lock "
                             f"{lock.name} is held); wait for it to end or choose another folder",
                             path=path) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino  # not a file its last holder removed meanwhile
        except OSError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        discard_unfinished([path], file_names)
        yield path
    finally:
        try:
            lock.unlink()
        except OSError:
            pass
        os.close(fd)


def _discard_stale_lock(lock: Path) -> bool:
    """Remove the lock file ``lock`` of a writer that was killed (no process holds it); True if removed.
    A lock some process holds (this one's included) is left alone."""
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False
    try:
        lock.unlink()
        return True
    except OSError:
        return False
    finally:
        os.close(fd)


def _lock_holder(fd: int) -> str:
    """`` (pid N)`` from a held lock file (its holder writes its pid), else ``""``."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return ""
    return f" (pid {text})" if text.isdigit() else ""


def _swap_in(tmp: Path, path: Path, parent: Path) -> None:
    """Rename ``tmp`` onto ``path``; an existing ``path`` goes aside first and is deleted after."""
    if not path.exists():
        os.replace(tmp, path)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=parent))
    try:
        os.replace(path, old / path.name)
        try:
            os.replace(tmp, path)
        except OSError:
            os.replace(old / path.name, path)  # put the old folder back
            raise
    finally:
        if path.exists():
            shutil.rmtree(old, ignore_errors=True)


#: The random part of the names :mod:`tempfile` gives (``mkstemp``, ``mkdtemp``).
_TEMP_TAIL = r"[a-z0-9_]{8}"


def discard_unfinished(paths: Iterable[str | Path], file_names: Iterable[str] = ()) -> list[Path]:
    """Undo what writers ended mid-way (killed: no ``finally`` of theirs ran) left of
    :func:`atomic_dir` ``(path)`` and of :func:`atomic_path` ``(path / name)`` for each of
    ``file_names``; call it only once those writers are gone.

    An earlier folder the writer had put aside (``.NAME.old.*``, killed between the two renames
    of the swap) is put back when ``path`` is missing; the temporary folders beside ``path``
    (``.NAME.*``), the temporary files of ``file_names`` inside it and a lock file no process
    holds any more (:func:`output_lock`) are removed.

    Returns:
        The temporary folders and files removed.
    """
    removed: list[Path] = []
    names = list(file_names)
    for path in map(Path, paths):
        if _discard_stale_lock(path.parent / LOCK_NAME.format(name=path.name)):
            removed.append(path.parent / LOCK_NAME.format(name=path.name))
    by_parent: dict[Path, list[Path]] = {}
    for path in map(Path, paths):
        by_parent.setdefault(path.parent, []).append(path)
    for parent, targets in by_parent.items():
        try:
            hidden = [entry for entry in parent.iterdir() if entry.name.startswith(".")]
        except OSError:
            continue
        for path in targets:
            name = re.escape(path.name)
            aside = [e for e in hidden if re.fullmatch(rf"\.{name}\.old\.{_TEMP_TAIL}", e.name)]
            for folder in aside:
                if not path.exists() and (folder / path.name).is_dir():
                    os.replace(folder / path.name, path)  # the earlier set, as it was
            staging = [e for e in hidden if re.fullmatch(rf"\.{name}\.{_TEMP_TAIL}", e.name)]
            for folder in aside + staging:
                shutil.rmtree(folder, ignore_errors=True)
                removed.append(folder)
            patterns = [rf"\.{re.escape(f)}\.{_TEMP_TAIL}{re.escape(Path(f).suffix)}" for f in names]
            for tmp in (path.iterdir() if patterns and path.is_dir() else ()):
                if any(re.fullmatch(p, tmp.name) for p in patterns):
                    tmp.unlink(missing_ok=True)
                    removed.append(tmp)
    return removed


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold back SIGINT (Ctrl-C) during the block; one that arrived goes to the handler that was
    in place when the block ends (Python's default, or ``gtvo``'s
    :func:`gtvo.core.interrupt.note_interrupt`: :class:`KeyboardInterrupt`).

    For steps that must not stop half-way (two renames that swap an output folder). Only the
    main thread can set signal handlers: elsewhere, or when the handler was not set from Python,
    the block runs unprotected; under an ignored SIGINT there is nothing to hold back.
    """
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or previous is None \
            or previous is signal.SIG_IGN:
        yield
        return
    caught: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        if not callable(previous):
            raise KeyboardInterrupt  # (SIG_DFL: the default action would have ended the process)
        previous(signal.SIGINT, None)


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask

