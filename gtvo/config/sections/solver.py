"""The ``solver`` section: which solver runs the tracker's and the window's optimisations."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from gtvo.core.settings import check_settings

SolverName = Literal["handrolled", "gtsam"]


@dataclass(frozen=True)
class SolverConfig:
    """Which solver runs each optimisation.

    Attributes:
        tracker: the frame tracker's: ``handrolled`` (vectorised LM, the notes' Algorithm 3) or ``gtsam``.
        window: the sliding window's: ``gtsam`` (LM on smart factors, the window's engine) or ``handrolled``.
    """

    tracker: SolverName = "handrolled"
    window: SolverName = "gtsam"

    def __post_init__(self) -> None:
        check_settings(self)

    @classmethod
    def both(cls, name: str) -> "SolverConfig":
        """One solver for the tracker and the window (the CLI's ``--solver``)."""
        return cls(tracker=name, window=name)  # type: ignore[arg-type]

    @classmethod
    def from_name(cls, name: str) -> "SolverConfig":
        """A solver name means both solvers, as ``--solver NAME`` (``OdometryConfig(solver="gtsam")``,
        ``solver: gtsam`` in a config file); :meth:`both`."""
        return cls.both(name)


