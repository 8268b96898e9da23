"""``--rerun FILE.rrd`` / ``--rerun-connect ADDRESS``: the Rerun viewer options of ``run`` and ``demo``."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path
from typing import Any, Iterator

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
    from gtvo.io.rerun_log import RerunLogger  # noqa: PLC0415  (rerun-sdk is imported here, not at start-up)

    with RerunLogger(save=args.rerun, connect=args.rerun_connect) as logger:
        yield [logger]


def _check_outside_output_folder(rrd: str | None, out: str | None) -> None:
    """InputError when the ``.rrd`` would lie in (or under) the ``--out`` folder: a run's outputs
    replace that folder as a set (:func:`gtvo.io.outputs.write_run_outputs`)."""
    if rrd is None or out is None:
        return
    folder, target = Path(out).resolve(), Path(rrd).resolve()
    if folder in target.parents:
        raise InputError(f"--rerun {rrd} is inside the output folder {out}, which the run replaces with its "
                         "output set: write the recording beside it")
