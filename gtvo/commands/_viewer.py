"""``--rerun FILE.rrd`` / ``--rerun-connect ADDRESS``: the Rerun viewer options of ``run`` and ``demo``."""

from __future__ import annotations

import argparse
import contextlib
import os
from typing import Any, Iterator

from gtvo.core.paths import resolved, same_or_inside
from gtvo.errors import InputError


def add_viewer_options(p: argparse.ArgumentParser) -> None:
    """Add ``--rerun`` and ``--rerun-connect`` (needs the ``viewer`` extra: ``pip install "gtvo[viewer]"``)."""
    p.add_argument("--rerun", metavar="FILE.rrd", default=None,
                   help="log the run to a Rerun recording as it goes (cameras, images, tracked points, window, "
                        "trajectory, map, plots); open it with `rerun FILE.rrd`. Needs pip install \"gtvo[viewer]\"")
    p.add_argument("--rerun-connect", metavar="ADDRESS", default=None,
                   help="log the run to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy "
                        "(the address `rerun` listens on by default)")


@contextlib.contextmanager
def viewer_observers(args: Any) -> Iterator[list[Any]]:
    """The run's observers for the parsed options: ``[]``, or a
    :class:`gtvo.io.rerun_log.RerunLogger` whose recording is kept only when the block succeeds (the
    CLI's ``tidy_on_failure`` then also removes the folders made for it). The ``.rrd`` may not lie
    in the ``--out`` folder, which a run replaces as a set."""
    if args.rerun is None and args.rerun_connect is None:
        yield []
        return
    _check_outside_output_folder(args.rerun, getattr(args, "out", None))
    _check_outside_the_log(args.rerun, getattr(args, "sequence", None))
    if args.rerun_connect is not None:
        check_viewer_answers(args.rerun_connect)
    # the SDK's own log lines (coloured, into any stderr) would repeat what gtvo says in one line
    os.environ.setdefault("RUST_LOG", "off")
    from gtvo.io.rerun_log import RerunLogger  # noqa: PLC0415  (rerun-sdk is imported here, not at start-up)

    with RerunLogger(save=args.rerun, connect=args.rerun_connect) as logger:
        yield [logger]


def _check_outside_output_folder(rrd: str | None, out: str | None) -> None:
    """InputError when the ``.rrd`` would lie in (or under) the ``--out`` folder: a run's outputs
    replace that folder as a set (:func:`gtvo.io.outputs.write_run_outputs`)."""
    if rrd is None or out is None:
        return
    folder, target = resolved(out, "output folder"), resolved(rrd, "--rerun file")
    if folder in target.parents or same_or_inside(target.parent, folder):  # (a folder not yet made: by name)
        raise InputError(f"--rerun {rrd} is inside the output folder {out}, which the run replaces with its "
                         "output set: write the recording beside it")


def _check_outside_the_log(rrd: str | None, log: str | None) -> None:
    """InputError when the ``.rrd`` would be written into the log folder or below it."""
    if rrd is None or log is None or not os.path.isdir(log):
        return
    if same_or_inside(resolved(rrd, "--rerun file").parent, log):
        raise InputError(f"--rerun {rrd} is inside the log {log}: a recording there would mix with its data; "
                         f"write it elsewhere")


#: Seconds :func:`check_viewer_answers` waits for a viewer to accept a connection.
CONNECT_TIMEOUT_S = 3.0


def check_viewer_answers(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """A one-line :class:`InputError` at once when nothing accepts a connection at the viewer's
    ``host:port`` (the Rerun SDK itself retries for about 10 s and then logs its own lines)."""
    import socket  # noqa: PLC0415
    from urllib.parse import urlsplit  # noqa: PLC0415

    try:
        parts = urlsplit(address)
        host, port = parts.hostname, parts.port
    except ValueError:
        return  # the logger names a malformed address
    if not host or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise InputError(f"--rerun-connect {address}: no Rerun viewer answers at {host}:{port} "
                         f"({exc.strerror or exc}); start `rerun` first, or record with --rerun FILE.rrd") from None
