"""Image core: float conversion, pyramids, gradients and bilinear sampling (one compiled loop for float32 images).

Pixel (0, 0) is the centre of the top-left pixel. A sample at (u, v) is valid when its four
bilinear neighbours are inside the image, i.e. ``0 <= u <= W-1`` and ``0 <= v <= H-1``
(optionally shrunk by a border); invalid samples return 0 and a False mask, never NaN.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.jit import jit
from gtvo.errors import InputError

FloatImage = NDArray[np.float32]


def to_float_gray(image: NDArray, name: str = "image") -> FloatImage:
    """Convert an 8/16-bit or float image (H, W) or (H, W, 3) to float32 gray in [0, 255] units.

    Colour images are taken as BGR (OpenCV's order) and converted with ITU-R BT.601 weights.
    16-bit images are scaled by 255 / 65535 (a camera that logs 16 bits is not 256x brighter);
    8-bit and float images keep their values. A 12-bit sensor stored in 16-bit files therefore
    comes out 16x darker than full range, and the grey-level constants (selection threshold,
    ``sigma_intensity``) stay in 8-bit units: scale such logs to full range first.
    """
    img = np.asarray(image)
    scale = 255.0 / 65535.0 if img.dtype == np.uint16 else None
    if img.ndim == 3 and img.shape[2] in (3, 4):
        b, g, r = img[..., 0].astype(np.float32), img[..., 1].astype(np.float32), img[..., 2].astype(np.float32)
        img = 0.114 * b + 0.587 * g + 0.299 * r
    elif img.ndim != 2:
        raise InputError(f"{name} must be a 2-D gray or 3-channel image, got shape {img.shape}")
    out = img.astype(np.float32, copy=False)
    if scale is not None:
        out = out * np.float32(scale)
    # an integer image converts to finite values: only float (and converted colour) images are checked
    if (img.dtype.kind not in "iub") and not np.all(np.isfinite(out)):
        raise InputError(f"{name} contains NaN or infinite values")
    return out


def as_float_gray(image: NDArray, name: str = "image") -> FloatImage:
    """``image`` itself when it is float32 gray (H, W) already, the form :func:`to_float_gray`
    returns and every reader's loader makes; else ``to_float_gray(image, name)``.

    For the images of a frame (:class:`gtvo.datasets.sequence.Frame`), converted and checked once
    where they were read: a float32 gray image is taken as that and not scanned again. Anything
    a user hands to the front end's public functions goes through :func:`to_float_gray` instead.
    """
    img = np.asarray(image)
    if img.dtype == np.float32 and img.ndim == 2:
        return img
    return to_float_gray(img, name)


def to_uint8(image: NDArray, name: str = "image") -> NDArray[np.uint8]:
    """A gray image (float in 8-bit units, uint8 or uint16) as uint8, for OpenCV's 8-bit routines."""
    img = np.asarray(image)
    if img.ndim != 2:
        raise InputError(f"{name} must be a 2-D gray image, got shape {img.shape}")
    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        return (img >> 8).astype(np.uint8)
    f = img.astype(np.float32, copy=False)
    if not np.all(np.isfinite(f)):
        raise InputError(f"{name} contains NaN or infinite values")
    return np.clip(np.rint(f), 0, 255).astype(np.uint8)


def downsample(image: NDArray) -> FloatImage:
    """Halve an image by 2x2 block averaging (DSO's pyramid); odd last rows/columns are dropped.

    One compiled pass (:func:`_downsample_loop`) for a 2-D image, the float32 values of the numpy
    form ``0.25 * (img[0::2, 0::2] + img[1::2, 0::2] + img[0::2, 1::2] + img[1::2, 1::2])``
    (the sums in that order), which other shapes keep.
    """
    img = np.asarray(image, dtype=np.float32)
    h, w = (img.shape[0] // 2) * 2, (img.shape[1] // 2) * 2
    if img.ndim == 2:
        return _downsample_loop(img, h // 2, w // 2)
    img = img[:h, :w]
    return 0.25 * (img[0::2, 0::2] + img[1::2, 0::2] + img[0::2, 1::2] + img[1::2, 1::2])


def build_pyramid(image: NDArray, levels: int, min_size: int = 16) -> list[FloatImage]:
    """Image pyramid ``[level 0 (full), level 1 (half), ...]``; stops early below ``min_size``.

    Level ``l`` matches :meth:`gtvo.core.camera.PinholeCamera.scaled` ``(l)``.
    """
    if levels < 1:
        raise InputError(f"pyramid needs at least one level, got {levels}")
    pyr = [np.asarray(image, dtype=np.float32)]
    while len(pyr) < levels and min(pyr[-1].shape[:2]) // 2 >= min_size:
        pyr.append(downsample(pyr[-1]))
    return pyr


def image_gradients(image: NDArray) -> tuple[FloatImage, FloatImage]:
    """Central-difference gradients ``(gx, gy)`` in intensity per pixel; one-sided at borders."""
    img = np.asarray(image, dtype=np.float32)
    gx = np.empty_like(img)
    gy = np.empty_like(img)
    gx[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    gx[:, 0] = img[:, 1] - img[:, 0]
    gx[:, -1] = img[:, -1] - img[:, -2]
    gy[1:-1, :] = 0.5 * (img[2:, :] - img[:-2, :])
    gy[0, :] = img[1, :] - img[0, :]
    gy[-1, :] = img[-1, :] - img[-2, :]
    return gx, gy


def bilinear_sample(image: NDArray, u: ArrayLike, v: ArrayLike,
                    border: float = 0.0) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Sample ``image`` (H, W) or (H, W, C) at float pixel positions, vectorised.

    Args:
        image: the image; a stack (H, W, C) samples all channels at once (e.g. I, gx, gy).
        u, v: column and row coordinates, any equal shapes.
        border: pixels kept free at each side for a sample to count as valid.

    Returns:
        ``(values, valid)``: values of shape ``u.shape`` (or ``u.shape + (C,)``), 0 where invalid;
        ``valid`` is True where the sample and its neighbours lie inside the image and u, v are finite.
    """
    img = np.asarray(image)
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    h, w = img.shape[:2]
    if img.dtype == np.float32 and img.ndim in (2, 3) and h >= 2 and w >= 2 and u.shape == v.shape:
        # the loop form below (one compiled pass, the same arithmetic in the same order)
        stack = np.ascontiguousarray(img.reshape(h, w, -1))
        vals, ok = _bilinear_loop(stack, np.ascontiguousarray(u).reshape(-1), np.ascontiguousarray(v).reshape(-1),
                                  float(border))
        shape = u.shape + ((img.shape[2],) if img.ndim == 3 else ())
        return vals.reshape(shape), ok.reshape(u.shape)
    valid = (np.isfinite(u) & np.isfinite(v)
             & (u >= border) & (u <= w - 1 - border) & (v >= border) & (v <= h - 1 - border))
    us = np.where(valid, u, 0.0)
    vs = np.where(valid, v, 0.0)
    x0 = np.minimum(np.floor(us).astype(np.intp), w - 2)
    y0 = np.minimum(np.floor(vs).astype(np.intp), h - 2)
    x0 = np.maximum(x0, 0)
    y0 = np.maximum(y0, 0)
    ax = us - x0
    ay = vs - y0
    flat = img.reshape(h * w, *img.shape[2:])
    i00 = y0 * w + x0
    v00 = flat[i00]
    v01 = flat[i00 + 1]
    v10 = flat[i00 + w]
    v11 = flat[i00 + w + 1]
    if img.ndim == 3:
        ax = ax[..., None]
        ay = ay[..., None]
    out = (1 - ay) * ((1 - ax) * v00 + ax * v01) + ay * ((1 - ax) * v10 + ax * v11)
    out = np.where(valid[..., None] if img.ndim == 3 else valid, out, 0.0)
    return out.astype(np.float64, copy=False), valid


def check_same_size(a: NDArray, b: NDArray, what: str) -> None:
    """Raise :class:`InputError` naming ``what`` when two images differ in size."""
    if a.shape[:2] != b.shape[:2]:
        raise InputError(f"{what}: image sizes differ, {a.shape[1]}x{a.shape[0]} vs {b.shape[1]}x{b.shape[0]}")


@jit
def bilinear_cell(u, v, w, h, border):
    """The bilinear cell of ``(u, v)`` in a (h, w) image under :func:`bilinear_sample`'s validity
    rule (finite, within ``border`` of no edge): ``(valid, x0, y0, ax, ay)``, the cell's top-left
    corner and the fractions (compiled; shared by the compiled samplers)."""
    if not (np.isfinite(u) and np.isfinite(v) and u >= border and u <= w - 1 - border
            and v >= border and v <= h - 1 - border):
        return False, 0, 0, 0.0, 0.0
    x0 = max(min(int(np.floor(u)), w - 2), 0)
    y0 = max(min(int(np.floor(v)), h - 2), 0)
    return True, x0, y0, u - x0, v - y0


@jit
def _bilinear_loop(stack, u, v, border):
    """:func:`bilinear_sample`'s numpy form as one loop over the samples of a (H, W, C) float32
    stack: the same validity rule and the same float64 arithmetic, in the same order."""
    h, w, c = stack.shape
    m = u.shape[0]
    out = np.zeros((m, c))
    valid = np.zeros(m, dtype=np.bool_)
    for k in range(m):
        ok, x0, y0, ax, ay = bilinear_cell(u[k], v[k], w, h, border)
        if not ok:
            continue
        valid[k] = True
        for ch in range(c):
            v00 = stack[y0, x0, ch]
            v01 = stack[y0, x0 + 1, ch]
            v10 = stack[y0 + 1, x0, ch]
            v11 = stack[y0 + 1, x0 + 1, ch]
            out[k, ch] = (1 - ay) * ((1 - ax) * v00 + ax * v01) + ay * ((1 - ax) * v10 + ax * v11)
    return out, valid


@jit
def _downsample_loop(img, h2, w2):
    """:func:`downsample` of a 2-D float32 image to (h2, w2): ``((a + b) + c) + d`` times 0.25 in
    float32, ``a, b`` the left column of a 2x2 block (top, bottom), ``c, d`` its right one."""
    out = np.empty((h2, w2), dtype=np.float32)
    quarter = np.float32(0.25)
    for y in range(h2):
        for x in range(w2):
            out[y, x] = quarter * (((img[2 * y, 2 * x] + img[2 * y + 1, 2 * x]) + img[2 * y, 2 * x + 1])
                                   + img[2 * y + 1, 2 * x + 1])
    return out
