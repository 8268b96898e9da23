"""Stand-ins for gtvo.batching.runners.run_log in tests: spawned pool workers import them."""

from __future__ import annotations

import os
from typing import Any


def crash_or_pass(job: dict[str, Any]) -> dict[str, Any]:
    """Kill this worker process when the job says so, else succeed at once."""
    if job.get("crash"):
        os._exit(9)
    return {"status": "done", "record": {"name": job["name"], "pid": os.getpid()}}


def stall_in_staging(job: dict[str, Any]) -> dict[str, Any]:
    """Write part of a run's output set into its staging folder (``gtvo.core.atomic.atomic_dir``),
    leave ``job["ready"]`` behind, then wait to be ended. With ``job["half_swapped"]`` the state a
    worker killed between the swap's two renames leaves: the earlier set moved aside into
    ``.NAME.old.*``, the new set still staged. A temporary ``batch.json`` sits in the folder too."""
    import tempfile
    import time
    from pathlib import Path

    from gtvo.core.atomic import atomic_dir
    from gtvo.io.outputs import RUN_OUTPUT_NAMES, RUN_WRITER

    out = Path(job["out"])
    with atomic_dir(out, RUN_OUTPUT_NAMES, RUN_WRITER) as staging:
        (staging / "trajectory.tum").write_text("0 0 0 0 0 0 0 1\n")
        if out.is_dir():
            tempfile.mkstemp(prefix=".batch.json.", suffix=".json", dir=out)
        if job.get("half_swapped"):
            aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
            os.replace(out, aside / out.name)
        Path(job["ready"]).write_text("ready\n")
        time.sleep(600)
    return {"status": "done", "record": {"name": job["name"]}}


def pass_or_sleep(job: dict[str, Any]) -> dict[str, Any]:
    """Succeed at once, or first sleep ``job["sleep"]`` seconds (then leave ``job["slept"]``, a file,
    when given: a worker ended during its sleep never writes it)."""
    import time
    from pathlib import Path

    time.sleep(job.get("sleep", 0))
    if job.get("slept"):
        Path(job["slept"]).write_text("slept\n")
    return {"status": "done", "record": {"name": job["name"], "pid": os.getpid()}}
