"""The window's residuals kept across its solves: what a host's last pass computed, per target.

A host's photometric residuals in one target (with their Jacobians) are a pure function of the
host's and the target's images, the host's points (pixels, pattern, camera), the two poses, the two
affines and the host's inverse depths; the stereo term's of the host's images, its inverse depths
and the rig offset. Each window solve builds new host factors and evaluates them first at the
state the last solve ended at, for every target but the newest; the marginalisation and the rig
offset's test then linearise hosts at that same state again. The last solve had computed exactly
these residuals (its last accepted trial) and thrown them away with its factors.

:func:`remember` keeps, per host keyframe, the residuals of its last pass with the state each
target's were computed at; :func:`recall` gives a new host's :class:`factors.host_points.HostPoints`
at a state the residuals of that state: those of the targets whose state is byte-equal to the
kept one (the same image objects, the same pose, affine and inverse-depth bytes), the others
computed there (:meth:`HostPoints.residual_calls`, the values of a whole pass to the bit). The
numbers are those of a new pass; only the work is not repeated.

Bounded: one entry per host keyframe whose image is alive (a window's few hosts; an entry goes
with its image, and at most :data:`MAX_HOSTS` are kept). Nothing is kept for a graph whose host
factors have a :class:`factors.smart.JacobianBudget` (the whole-log refinement's: its callers do
not remember). The kept arrays are read, never written: a new pass writes into its own buffers.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from factors.host_points import HostPoints, PassLinearizations
from factors.photometric import PhotometricLinearization
from gtvo.core.timing import stage

FloatArray = NDArray[np.float64]

#: at most this many hosts' residuals are kept (a window has a few; dead images are pruned first)
MAX_HOSTS = 16


@dataclass(frozen=True)
class _TargetPass:
    """One target's residuals of a host's kept pass and what they were computed from."""

    image: weakref.ref  #: the target image (the same object, not an equal one)
    state: bytes  #: the target's pose matrix and affine, as bytes
    lin: PhotometricLinearization


@dataclass(frozen=True)
class _HostPass:
    """A host's kept pass: its points (by the arrays of their samples), its state, per target
    the residuals, and the stereo term's (None: none kept)."""

    image: weakref.ref  #: the host's (left) image
    bearings: FloatArray  #: the host points' bearings (the host samples' array: identity = same points)
    intensity: FloatArray  #: the host intensities at the pattern (the same, by identity)
    state: bytes  #: the host's pose matrix, affine and inverse depths, as bytes
    targets: dict[int, _TargetPass]  #: by ``id`` of the target image
    #: (the right image, the stereo term's key, its residuals); None: none kept
    stereo: tuple[weakref.ref, bytes, PhotometricLinearization] | None


@dataclass(frozen=True)
class HostState:
    """The state a host's residuals are computed at: ``poses`` (``gtsam.Pose3`` or 4x4: the host's,
    then its targets' in order), ``affines`` (the same order; ignored without affines), the host's
    inverse depths ``d`` (N,) and the stereo term's rig offset ``offset`` (None: none)."""

    poses: Sequence
    affines: Sequence
    d: FloatArray
    offset: object | None = None


#: per host image (``id``), the residuals of its last remembered pass
_PASSES: dict[int, _HostPass] = {}


def _copy(lin: PhotometricLinearization) -> PhotometricLinearization:
    """A new linearisation object with the same arrays (a caller may rebind its attributes)."""
    out = object.__new__(type(lin))
    out.__dict__.update(lin.__dict__)
    return out


def _matrix_bytes(pose: object) -> bytes:
    return np.asarray(pose.matrix() if hasattr(pose, "matrix") else pose, dtype=float).tobytes()


def _vector_bytes(v: object) -> bytes:
    return np.asarray(v, dtype=float).tobytes()


def _host_state(points: HostPoints, pose: object, affine: object, d: FloatArray) -> bytes:
    aff = _vector_bytes(affine) if points.with_affine else b""
    return b"|".join([_matrix_bytes(pose), aff, _vector_bytes(d)])


def _target_state(points: HostPoints, pose: object, affine: object) -> bytes:
    return _matrix_bytes(pose) + b"|" + (_vector_bytes(affine) if points.with_affine else b"")


def _stereo_key(points: HostPoints, offset: object | None) -> bytes:
    """What the stereo term's residuals depend on besides the host's points and depths."""
    return b"|".join([b"rig" if points.rig else b"", b"" if offset is None else _vector_bytes(offset),
                      _vector_bytes(points.stereo_affine), _vector_bytes(points.baseline or 0.0)])


def _same_points(entry: _HostPass, points: HostPoints, host_image: object) -> bool:
    return (entry.image() is host_image and entry.bearings is points.bearings
            and entry.intensity is points.host_intensity)


def remember(points: HostPoints, host_image: object, state: HostState, lins: Sequence) -> None:
    """Keep ``lins``, the residuals of every target of ``points`` then the stereo term's (or None),
    with Jacobians, at ``state``, as the host's last pass (the previous one goes).
    ``host_image``: the host keyframe's image (the entry lives as long as it does)."""
    poses, affines, d, offset = state.poses, state.affines, state.d, state.offset
    if len(lins) != len(points.target_images) + 1 or any(
            lin is None or lin.J_host is None or not lin.has_pair_pose for lin in lins[:-1]):
        return  # not a whole pass with its Jacobians: nothing to reuse
    targets = {}
    for t, (img, lin) in enumerate(zip(points.target_images, lins)):
        state_t = _target_state(points, poses[1 + t], affines[1 + t] if points.with_affine else None)
        targets[id(img)] = _TargetPass(weakref.ref(img), state_t, lin)
    stereo = lins[-1]
    kept_stereo = None
    if stereo is not None and (not points.rig or stereo.J_offset is not None):
        kept_stereo = (weakref.ref(points.right_image), _stereo_key(points, offset), stereo)
    _prune()
    _PASSES[id(host_image)] = _HostPass(weakref.ref(host_image), points.bearings, points.host_intensity,
                                        _host_state(points, poses[0], affines[0] if points.with_affine else None, d),
                                        targets, kept_stereo)


def forget(host_image: object) -> None:
    """Drop the host's kept residuals (it left the window)."""
    entry = _PASSES.get(id(host_image))
    if entry is not None and entry.image() is host_image:
        del _PASSES[id(host_image)]


def _prune() -> None:
    for k in [k for k, v in _PASSES.items() if v.image() is None]:
        del _PASSES[k]
    while len(_PASSES) >= MAX_HOSTS:
        del _PASSES[next(iter(_PASSES))]


def recall(points: HostPoints, host_image: object, state: HostState) -> PassLinearizations | None:
    """The residuals (with Jacobians) of every target of ``points`` and its stereo term at
    ``state``: the kept ones of the targets whose state is byte-equal, the others computed here;
    None when nothing is kept for this state (the caller's pass computes them all)."""
    poses, affines, d, offset = state.poses, state.affines, state.d, state.offset
    entry = _PASSES.get(id(host_image))
    if entry is None or not _same_points(entry, points, host_image):
        return None
    if entry.state != _host_state(points, poses[0], affines[0] if points.with_affine else None, d):
        return None
    kept: list[PhotometricLinearization | None] = []
    for t, img in enumerate(points.target_images):
        hit = entry.targets.get(id(img))
        if hit is not None and (hit.image() is not img or hit.state != _target_state(
                points, poses[1 + t], affines[1 + t] if points.with_affine else None)):
            hit = None
        kept.append(None if hit is None else _copy(hit.lin))
    has_stereo = points.right_image is not None
    stereo = None
    if (has_stereo and entry.stereo is not None and entry.stereo[0]() is points.right_image
            and entry.stereo[1] == _stereo_key(points, offset)):
        stereo = _copy(entry.stereo[2])
    if not any(lin is not None for lin in kept) and stereo is None:
        return None
    missing = [t for t, lin in enumerate(kept) if lin is None] + ([len(kept)] if has_stereo and stereo is None else [])
    if missing:
        with stage("linearisation"):
            calls = points.residual_calls(poses, affines, d, offset=offset, jacobians=True)
            for t in missing:
                if t < len(kept):
                    kept[t] = calls[t]()
                else:
                    stereo = calls[-1]()
    items = kept + [stereo]
    # as a pass's: the items' residuals are the rows of the stack the point costs read (a copy)
    stack = np.stack([lin.residual for lin in items if lin is not None])
    for row, lin in zip(stack, [lin for lin in items if lin is not None]):
        lin.residual = row
    return PassLinearizations(items, stack)
