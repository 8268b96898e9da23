"""Paths as the file system sees them: resolved without a traceback, compared by identity.

Two spellings of one folder (``a/b/..``, a symbolic link, a bind mount, another case on a
case-insensitive disk) are one folder: :func:`same_or_inside` compares the device and inode
numbers (``st_dev``, ``st_ino``) of a path and of each of its ancestors with those of the
folder, as ``os.path.samefile`` does, rather than strings. :func:`resolved` is
:meth:`pathlib.Path.resolve` that reports a symbolic link loop as a one-line
:class:`gtvo.errors.InputError` naming the path (Python raises ``RuntimeError`` there).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

from gtvo.errors import InputError

#: A file's identity on this machine: ``(st_dev, st_ino)``.
FileIdentity = tuple[int, int]


def resolved(path: str | Path, what: str = "path") -> Path:
    """``path`` made absolute with every symbolic link followed (a missing tail kept as written).

    Raises:
        InputError: ``path`` (or a link on the way) is a symbolic link loop, naming ``what``.
    """
    try:
        return Path(path).resolve()
    except RuntimeError:  # Python < 3.13: "Symlink loop from ..."
        raise InputError(f"{what} is a symbolic link loop", path=path) from None
    except OSError as exc:  # Python >= 3.13 raises the system's ELOOP
        if exc.errno == errno.ELOOP:
            raise InputError(f"{what} is a symbolic link loop", path=path) from None
        raise InputError(f"{what} cannot be resolved ({exc.strerror or exc})", path=path) from None


def link_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be followed (``"a symbolic link loop"``, ``"a broken symbolic link"``),
    or None when it can (or is no link and simply absent)."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link loop"
        if exc.errno == errno.ENOENT and os.path.islink(path):
            return f"a broken symbolic link (to {os.readlink(path)})"
    return None


def identity(path: str | Path) -> FileIdentity | None:
    """``(st_dev, st_ino)`` of ``path`` (links followed), None when it cannot be read."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def existing_ancestors(path: str | Path) -> list[Path]:
    """``path`` (when it exists) and every folder above it, innermost first, after following its
    links (a part not yet made is skipped: it cannot be another folder)."""
    real = Path(os.path.realpath(os.path.abspath(path)))
    return [p for p in (real, *real.parents) if os.path.lexists(p)]


def same_or_inside(path: str | Path, folder: str | Path) -> bool:
    """True when ``path`` is ``folder`` or lies inside it, by file identity (whatever the
    spelling: ``..``, symbolic links, bind mounts). A ``folder`` that does not exist holds nothing."""
    target = identity(folder)
    if target is None:
        return False
    return any(identity(p) == target for p in existing_ancestors(path))


def check_not_an_input(output: str | Path | None, inputs: dict[str, str | Path | None], flag: str) -> None:
    """A one-line :class:`InputError` when the output file ``output`` (given as ``flag``) is one of
    the command's ``inputs`` (``{"its flag or name": path}``) or lies inside an input folder, by file
    identity (a link, '..', a bind mount): no command writes over or into what it reads."""
    if not output:
        return
    real = os.path.realpath(output)  # (a part not yet made, as in 'new/../input', collapsed as the system will)
    for name, given in inputs.items():
        if not given:
            continue
        if identity(real) is not None and identity(real) == identity(given):
            raise InputError(f"{flag} is the {name} {given} itself: writing it would replace the input; "
                             f"choose another file", path=output)
        if os.path.isdir(given) and same_or_inside(Path(real).parent, given):
            raise InputError(f"{flag} is inside the {name} {given}: outputs there would mix with its data; "
                             f"write it elsewhere", path=output)
