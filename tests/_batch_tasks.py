"""Stand-ins for gtvo.batching.runners.run_log in tests: spawned pool workers import them."""

from __future__ import annotations

import os
from typing import Any


def crash_or_pass(job: dict[str, Any]) -> dict[str, Any]:
    """Kill this worker process when the job says so, else succeed at once."""
    if job.get("crash"):
        os._exit(9)
    return {"status": "done", "record": {"name": job["name"], "pid": os.getpid()}}
