"""A compiled row copy between the window's pass buffers (:class:`factors.host_points.PassBuffers`).

The safeguarded depth step (:meth:`factors.host_points.HostPoints.safeguard`) puts the points that
go back to their old depth into a trial pass's buffers: a few hundred scattered rows of every
term's residuals, Jacobians and warped pixels (and :func:`factors.photometric.put_rows` the rows
of one linearisation into another's, when the passes were made apart). numpy's ``a[:, rows] = b[:, other_rows]`` gathers
into a temporary and scatters it again (about 5x this loop's time on a KITTI host). Compiled on first
use and cached on disk (:func:`gtvo.core.jit.jit`).
"""

from __future__ import annotations

from gtvo.core.jit import jit


@jit
def copy_rows(dst, dst_rows, src, src_rows):
    """``dst[t, dst_rows[i], :] = src[t, src_rows[i], :]`` for every ``t`` and ``i``: ``dst`` and ``src``
    (T, N, K) and (T, M, K) of one dtype, ``dst_rows`` and ``src_rows`` of one length (indices are
    not checked: the caller's come from the same points)."""
    for t in range(dst.shape[0]):
        for i in range(dst_rows.shape[0]):
            a, b = dst_rows[i], src_rows[i]
            for k in range(dst.shape[2]):
                dst[t, a, k] = src[t, b, k]
