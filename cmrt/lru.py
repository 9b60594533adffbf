"""The one in-memory cache of the product: at most `maxsize` values by key, the least recently
used dropped first, safe to share between threads (the API answers and the drivers run on
several). Every process-local cache (typed specs and simulators, job spec hashes, library
records and query specs) is one of these."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class LRU(Generic[K, V]):
    """At most `maxsize` values by key; `get` and `put` make a key the most recently used."""

    def __init__(self, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize: must be at least 1, got {maxsize}")
        self.maxsize = maxsize
        self._values: OrderedDict[K, V] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._values)

    def __contains__(self, key: object) -> bool:
        return key in self._values

    def get(self, key: K, default: V | None = None) -> V | None:
        """The value of `key` (now the most recently used), else `default`."""
        with self._lock:
            if key not in self._values:
                return default
            self._values.move_to_end(key)
            return self._values[key]

    def put(self, key: K, value: V) -> list[tuple[K, V]]:
        """Keep `value` under `key` as the most recently used; returns the (key, value) pairs
        dropped to stay within `maxsize`, oldest first."""
        with self._lock:
            self._values[key] = value
            self._values.move_to_end(key)
            dropped = []
            while len(self._values) > self.maxsize:
                dropped.append(self._values.popitem(last=False))
            return dropped

    def peek(self, key: K, default: V | None = None) -> V | None:
        """The value of `key` without making it the most recently used, else `default`."""
        with self._lock:
            return self._values.get(key, default)

    def get_or_make(self, key: K, make: Callable[[], V]) -> V:
        """The value of `key`; on a miss `make()` builds it and it is kept. `make` runs outside
        the lock (two threads missing at once may both make it; the later one is kept)."""
        with self._lock:
            if key in self._values:
                self._values.move_to_end(key)
                return self._values[key]
        value = make()
        self.put(key, value)
        return value

    def pop(self, key: K, default: V | None = None) -> V | None:
        """Remove `key`; its value, else `default`."""
        with self._lock:
            return self._values.pop(key, default)

    def clear(self) -> None:
        with self._lock:
            self._values.clear()


__all__ = ["LRU"]
