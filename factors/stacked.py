"""Several Python factors as one GTSAM factor: :class:`StackedFactors`.

Every call of a Python factor from inside a GTSAM optimiser receives a copy of the whole ``Values``
(the team's measured facts about the GTSAM wheel, docs/factors.md), so an optimiser iteration costs
O(Python factors x variables): over a whole log, K host factors and K motion priors on 2K variables
make that part grow as K^2 (docs/refinement.md, "Cost"). Stacking ``G`` of them into one factor
divides the copies by ``G``: the stacked factor calls its members from Python (no copy) and
returns their whitened errors and Jacobians one under the other, so its cost is the sum of theirs
and its linearisation has exactly their rows; only the order in which the elimination adds them
changes (rounding).
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np

from factors.gtsam_factors import PythonFactor
from gtvo.errors import InputError


class StackedFactors(PythonFactor):
    """``members`` (Python factors with Gaussian noise models) as one factor on the union of their keys.

    Error: each member's whitened error, stacked in order (dimension: the sum of theirs); noise
    model: unit. Jacobian of a key: each member's whitened Jacobian in its rows, zeros in the
    rows of the members without that key. The members keep their own state (e.g. a
    :class:`factors.smart.HostPointsFactor`'s depths and caches) and are called as GTSAM would call them.

    Raises:
        InputError: no member, or a member with a robust noise model (its whitening depends on
            the error: not stacked).
    """

    def __init__(self, members: Sequence[PythonFactor]) -> None:
        self.members = list(members)
        if not self.members:
            raise InputError("StackedFactors needs at least one factor")
        keys: list[int] = []
        for m in self.members:
            if isinstance(m.noiseModel(), gtsam.noiseModel.Robust):
                raise InputError(f"StackedFactors: {type(m).__name__} has a robust noise model (not stacked)")
            keys += [k for k in m.keys() if k not in keys]
        self.noise_models = [m.noiseModel() for m in self.members]
        self.member_dims = [int(n.dim()) for n in self.noise_models]
        #: per member, the positions of its keys among the stacked factor's
        self.slots = [[keys.index(k) for k in m.keys()] for m in self.members]
        self.n_keys = len(keys)
        super().__init__(gtsam.noiseModel.Unit.Create(sum(self.member_dims)), keys)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        rows = sum(self.member_dims)
        out = np.empty(rows)
        blocks: list[np.ndarray | None] = [None] * self.n_keys
        row = 0
        for m, noise, dm, slots in zip(self.members, self.noise_models, self.member_dims, self.slots):
            Hm = None if H is None else [None] * len(slots)
            out[row:row + dm] = noise.whiten(np.asarray(m._evaluate(m, values, Hm), dtype=float))
            if Hm is not None:
                for s, J in zip(slots, Hm):
                    J = noise.Whiten(np.asarray(J, dtype=float))
                    if blocks[s] is None:
                        blocks[s] = np.zeros((rows, J.shape[1]))
                    blocks[s][row:row + dm] = J
            row += dm
        if H is not None:
            for s, b in enumerate(blocks):
                H[s] = b
        return out


def stacked(factors: Sequence[PythonFactor], size: int) -> list[PythonFactor]:
    """``factors`` in runs of ``size`` consecutive ones, each run a :class:`StackedFactors` (a run
    of one stays itself); ``size`` 1: the factors as they are."""
    if size <= 1:
        return list(factors)
    runs = [list(factors[i:i + size]) for i in range(0, len(factors), size)]
    return [r[0] if len(r) == 1 else StackedFactors(r) for r in runs]
