"""`cmrt.lru.LRU`, the product's one in-memory cache: bounded, least recently used dropped
first, safe to share between threads."""

from __future__ import annotations

import threading

import pytest

from cmrt.lru import LRU


def test_the_least_recently_used_key_is_dropped_first():
    cache: LRU[str, int] = LRU(2)
    assert cache.put("a", 1) == [] and cache.put("b", 2) == []
    assert cache.get("a") == 1  # "b" is now the least recently used
    assert cache.put("c", 3) == [("b", 2)]
    assert "b" not in cache and len(cache) == 2 and cache.get("b", -1) == -1
    assert cache.peek("a") == 1 and cache.put("d", 4) == [("a", 1)]  # peek does not refresh
    assert cache.pop("c") == 3 and cache.pop("c") is None and len(cache) == 1
    cache.clear()
    assert len(cache) == 0


def test_get_or_make_makes_only_on_a_miss():
    cache: LRU[int, str] = LRU(3)
    made = []

    def make(k: int) -> str:
        made.append(k)
        return str(k)

    assert [cache.get_or_make(k, lambda k=k: make(k)) for k in (1, 2, 1, 3, 4, 1)] == \
        ["1", "2", "1", "3", "4", "1"]
    assert made == [1, 2, 3, 4] and 2 not in cache and len(cache) == 3


def test_a_cache_holds_at_least_one_value():
    with pytest.raises(ValueError, match="maxsize"):
        LRU(0)


def test_threads_sharing_one_cache_keep_it_within_its_size():
    cache: LRU[int, int] = LRU(50)

    def work(offset: int) -> None:
        for i in range(2000):
            cache.put((i * 7 + offset) % 120, i)
            cache.get((i + offset) % 120)

    threads = [threading.Thread(target=work, args=(n,)) for n in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(cache) == 50
