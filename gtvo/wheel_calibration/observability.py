"""Which parameters a least-squares problem cannot determine, read from the SVD of its normal matrix.

Shared by the linear and the differential-drive calibrations. A direction ``v`` in parameter space
with ``v^T H v ~ 0`` (a singular value of ``H`` below ``rcond * s_max``) changes no residual: the
data says nothing about it. We name the parameters that dominate each such direction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError

#: Singular values of the normal matrix below ``DEFAULT_RCOND * s_max`` count as zero.
#: (H = J^T J squares the conditioning of J: 1e-12 on H is about 1e-6 on J.)
DEFAULT_RCOND: float = 1e-12


@dataclass(frozen=True)
class Observability:
    """SVD of a normal matrix: singular values, null directions and a readable verdict."""

    singular_values: NDArray[np.float64]
    null_directions: NDArray[np.float64]  # (k, p), each row a unit vector in parameter space
    rcond: float

    @property
    def rank(self) -> int:
        """Number of determined parameter directions."""
        return int(self.singular_values.size - self.null_directions.shape[0])

    @property
    def condition_number(self) -> float:
        """s_max / s_min of the normal matrix (inf when singular)."""
        s = self.singular_values
        return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")

    @property
    def observable(self) -> bool:
        """True when every parameter direction is determined."""
        return self.null_directions.shape[0] == 0


def analyse_normal_matrix(h: NDArray[np.float64], rcond: float = DEFAULT_RCOND) -> Observability:
    """SVD of the symmetric normal matrix ``h``; directions with ``s < rcond * s_max`` are unobservable."""
    _, s, vt = np.linalg.svd(h)
    smax = s[0] if s.size and s[0] > 0 else 0.0
    null = s <= rcond * smax if smax > 0 else np.ones_like(s, dtype=bool)
    return Observability(singular_values=s, null_directions=vt[null], rcond=rcond)


def describe_direction(v: NDArray[np.float64], names: Sequence[str], threshold: float = 0.05) -> str:
    """A null direction as text: one name if it is (nearly) one parameter, else the signed combination."""
    idx = [int(i) for i in np.flatnonzero(np.abs(v) > threshold)]
    if len(idx) == 1:
        return names[idx[0]]
    k = idx[int(np.argmax(np.abs(v[idx])))]
    v = v * np.sign(v[k])
    return "the combination " + " ".join(f"{'+' if v[i] >= 0 else '-'} {abs(v[i]):.3g}*{names[i]}" for i in idx).lstrip("+ ")


def raise_if_unobservable(obs: Observability, names: Sequence[str], reasons: Sequence[str] = (),
                          what: str = "calibration") -> None:
    """InputError naming each unobservable parameter (direction), with known ``reasons`` appended."""
    if obs.observable:
        return
    parts = [describe_direction(v, names) for v in obs.null_directions]
    msg = (f"{what}: {', '.join(parts)} {'is' if len(parts) == 1 else 'are'} unobservable "
           f"(normal matrix rank {obs.rank} of {obs.singular_values.size}, condition {obs.condition_number:.3g})")
    if reasons:
        msg += ": " + "; ".join(reasons)
    raise InputError(msg)
