"""A :class:`factors.photometric.GradientImage` that keeps only its grey levels between uses:
:class:`CompactGradientImage`, and the bounded cache of packed records it shares (:class:`PackedCache`).

A ``GradientImage`` holds its image (float32, 4 bytes a pixel) and, for the compiled sampler, one
16-byte record a pixel (intensity, the two gradients, the clipped-cell flag): 20 bytes a pixel, 9.3
MB at KITTI's 1241 x 376. A keyframe that has left the sliding window is needed again only by the
whole-log refinement (docs/refinement.md, "Cost"), so the window keeps it compact: the grey levels
alone (uint8 when they are whole grey levels in 0..255, as a camera's 8-bit image is: 1 byte a
pixel; else float32), and the records are packed again when the image is sampled, by the same
compiled pass (:func:`factors._compiled.pack_gradient_image`) from the same float32 values, so
every sample is bit-identical to the full image's. The packed records of the images used most
recently stay in a :class:`PackedCache` up to its byte budget; a whole-log pass, which visits the
host factors in the keyframes' order, packs each image about once.
"""

from __future__ import annotations

from collections import OrderedDict
from contextlib import contextmanager
from typing import Iterator

import numpy as np
from numpy.typing import NDArray

from factors import _compiled
from factors.photometric import GradientImage

#: The shared cache's budget outside a :func:`packed_cache_budget` block: 64 MiB of packed records
#: (8 KITTI-sized images, 54 at 320 x 240).
DEFAULT_PACKED_CACHE_BYTES = 64 * 2**20


class PackedCache:
    """The packed records of the compact images used most recently, at most ``max_bytes`` of them
    (least recently used evicted first; the newest is kept even when it alone is over the budget)."""

    def __init__(self, max_bytes: int = DEFAULT_PACKED_CACHE_BYTES) -> None:
        self.max_bytes = int(max_bytes)
        self._held: OrderedDict[int, CompactGradientImage] = OrderedDict()
        self.bytes = 0
        #: how many times an image was packed (a measure of the cache's misses)
        self.packs = 0

    def touch(self, image: CompactGradientImage) -> None:
        """Mark ``image`` (holding its records) as the most recently used."""
        self._held.move_to_end(id(image))

    def add(self, image: CompactGradientImage, nbytes: int) -> None:
        """Hold ``image``'s new records (``nbytes``), evicting the least recently used beyond the budget."""
        self.packs += 1
        self._held[id(image)] = image
        self.bytes += nbytes
        self.shrink(keep_newest=True)

    def shrink(self, keep_newest: bool = False) -> None:
        """Drop the least recently used records until the held ones fit the budget (``keep_newest``:
        never the most recent)."""
        while self.bytes > self.max_bytes and len(self._held) > int(keep_newest):
            _, old = self._held.popitem(last=False)
            self.bytes -= old.drop_records()

    def clear(self) -> None:
        """Drop every held record."""
        while self._held:
            _, old = self._held.popitem(last=False)
            old.drop_records()
        self.bytes = 0


#: The cache every :class:`CompactGradientImage` uses unless given its own.
SHARED_PACKED_CACHE = PackedCache()


@contextmanager
def packed_cache_budget(max_bytes: int, cache: PackedCache | None = None) -> Iterator[PackedCache]:
    """``cache`` (default :data:`SHARED_PACKED_CACHE`) with the budget ``max_bytes`` inside the
    block (e.g. the whole-log refinement's solve: every image's records at once when they fit,
    each packed once), its own again after it, the records beyond it dropped."""
    cache = SHARED_PACKED_CACHE if cache is None else cache
    before = cache.max_bytes
    cache.max_bytes = int(max_bytes)
    try:
        yield cache
    finally:
        cache.max_bytes = before
        cache.shrink()


class CompactGradientImage(GradientImage):
    """``source``'s grey levels, its sampler's records packed again on demand (module docstring).

    Samples, validity and clipping are ``source``'s bit for bit; :attr:`image` and :attr:`stack`
    are made when read (float32 copies). ``cache``: where its packed records are held
    (default :data:`SHARED_PACKED_CACHE`).
    """

    def __init__(self, source: GradientImage, cache: PackedCache | None = None) -> None:  # noqa: D107
        # not GradientImage.__init__: the source's checks and flags are taken as they are
        grey = np.asarray(source.image, dtype=np.float32)
        whole = grey.astype(np.uint8)
        self._grey: NDArray = whole if np.array_equal(whole.astype(np.float32), grey) else grey.copy()
        self.height, self.width = source.height, source.width
        self.border = source.border
        self.clip_range = source.clip_range
        self.has_clipped = source.has_clipped
        self._cache = SHARED_PACKED_CACHE if cache is None else cache
        self._records: NDArray[np.float32] | None = None

    def __getstate__(self) -> dict:
        """Pickled as its grey levels and flags: no packed records, no cache (e.g. a parallel
        window's keyframes coming back from its worker process)."""
        state = dict(self.__dict__)
        state["_records"] = None
        del state["_cache"]
        return state

    def __setstate__(self, state: dict) -> None:
        """Unpickled into this process's :data:`SHARED_PACKED_CACHE`."""
        self.__dict__.update(state)
        self._cache = SHARED_PACKED_CACHE

    @property
    def nbytes(self) -> int:
        """Bytes it keeps between uses (its grey levels)."""
        return int(self._grey.nbytes)

    @property
    def image(self) -> NDArray[np.float32]:  # type: ignore[override]
        """The image in 8-bit units, float32 (a new array)."""
        return self._grey.astype(np.float32)

    @property
    def stack(self) -> NDArray[np.float32]:  # type: ignore[override]
        """(H, W, 3) float32: intensity and its central-difference gradients (packed on demand)."""
        return self._packed_records().reshape(self.height, self.width, 4)[..., :3]

    def drop_records(self) -> int:
        """Forget the packed records (the cache's eviction); returns the bytes freed."""
        freed = 0 if self._records is None else int(self._records.nbytes)
        self._records = None
        return freed

    def _packed_records(self) -> NDArray[np.float32]:
        if self._records is not None:
            self._cache.touch(self)
            return self._records
        lo, hi = (0.0, 0.0) if self.clip_range is None else self.clip_range
        packed, _, _ = _compiled.pack_gradient_image(np.ascontiguousarray(self.image), np.float32(lo),
                                                     np.float32(hi), self.clip_range is not None)
        records = packed.reshape(-1, 4)
        self._records = records
        self._cache.add(self, int(records.nbytes))
        return records

    def _sampler_args(self) -> tuple:
        return (self._packed_records(), self.has_clipped, self.width, self.height, self.border)


def compact_image(image: GradientImage | None, cache: PackedCache | None = None) -> GradientImage | None:
    """``image`` as a :class:`CompactGradientImage` (itself when it is one already; None stays None)."""
    if image is None or isinstance(image, CompactGradientImage):
        return image
    return CompactGradientImage(image, cache)
