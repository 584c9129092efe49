"""A least-recently-used cache with a byte bound: a capture's images, the viewport's posed Gaussians;
never more than the bound in memory (a value larger than the bound alone is not kept)."""

from __future__ import annotations

import collections
import threading


class ByteLRU:
    """A thread-safe least-recently-used cache whose values' ``nbytes`` sum stays <= a bound."""

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self.nbytes = 0
        self._items: collections.OrderedDict = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        """The value cached under ``key`` (now the most recently used), or None."""
        with self._lock:
            item = self._items.get(key)
            if item is None:
                return None
            self._items.move_to_end(key)
            return item[0]

    def put(self, key, value, size: int) -> None:
        if size > self.max_bytes:
            return  # never cached: it alone would break the bound
        with self._lock:
            if key in self._items:
                return
            while self._items and self.nbytes + size > self.max_bytes:
                _, (_, old) = self._items.popitem(last=False)
                self.nbytes -= old
            self._items[key] = (value, size)
            self.nbytes += size

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self.nbytes = 0
