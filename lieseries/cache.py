"""One cache for what is expensive to build (compiled integrators, their plans, compiled programs), and one pool of
integrator copies.

The cache is cut into named regions (``"taylor.integrators"``, ``"expr.programs"``, ...), each bounded by a number
of entries; all regions share one lock (taken only to add or drop entries), one recency order and one eviction
policy: when a region is full, or when the build cost of everything cached (seconds spent compiling, where the
owner reports it) exceeds :data:`MAX_COST`, the least recently added or used entry goes first (of that region when
the region is full; of any region holding a cost when the cost is exceeded). :func:`clear` forgets everything at
once (a scene run starts with it so that the build times it reports are its own); :func:`info` counts the entries
of each region.

The hit path is one dict lookup (``region.get(key)``, the bound ``get`` of the region's dict, no lock): the memo of
repeated :func:`lieseries.integrate` calls is on it. An owner that wants a hit to count as a use calls
``region.touch(key)`` as well (an integrator build does: a compiled integrator in use is the last to be evicted).

The pool: heyoka integrators are not thread-safe, so no run integrates on a cached integrator (the *template*)
itself; it checks out a copy (:func:`checkout`), runs, and gives it back (:func:`release`). Free copies are kept per
template while the template is cached, at most :data:`MAX_FREE` of them; a template's copies go with it when it is
evicted. ``list.pop`` and ``list.append`` are atomic, so the pool needs no lock either.
"""

from __future__ import annotations

import copy
import threading
from collections import OrderedDict

__all__ = ["Region", "region", "clear", "info", "checkout", "release", "free_copies", "add_template", "drop_template", "MAX_COST",
           "MAX_FREE"]

#: Seconds of build time the whole cache may hold before its least recently used costly entries are dropped
#: (a rigid body compiles in ~0.1 s in double, a batch of 16 lanes in ~30 s).
MAX_COST = 600.0
#: Free copies kept per cached integrator (more runs of one integrator at once than this make throwaway copies).
MAX_FREE = 8

_LOCK = threading.RLock()
_REGIONS: dict = {}  # name -> Region
_ORDER: OrderedDict = OrderedDict()  # (region name, key) -> cost, least recently added or used first
_COST = [0.0]
_FREE: dict = {}  # id(template) -> (template, list of free copies)


class Region:
    """A named part of the cache, bounded by ``max_entries``. ``get(key)`` is the dict's own lookup (None on a
    miss); ``put`` (or ``region[key] = value``, ``setdefault``) adds (and evicts); ``touch`` marks a hit as a use;
    ``clear`` empties the region."""

    __slots__ = ("name", "max_entries", "data", "get", "on_evict")

    def __init__(self, name: str, max_entries: int, on_evict=None):
        self.name = name
        self.max_entries = int(max_entries)
        self.data: dict = {}
        self.get = self.data.get  # the hit path: one dict lookup
        self.on_evict = on_evict  # called with an evicted value, under the cache's lock: keep it cheap

    def put(self, key, value, cost: float = 0.0):
        """Cache ``value`` under ``key`` (or return the value another thread cached first); ``cost`` is its build
        time in seconds."""
        with _LOCK:
            found = self.data.get(key)
            if found is not None:
                return found
            while len(self.data) >= self.max_entries:
                _evict(self.name, next(k for (r, k) in _ORDER if r == self.name))
            self.data[key] = value
            cost = max(float(cost), 0.0)
            _ORDER[(self.name, key)] = cost
            _COST[0] += cost
            while _COST[0] > MAX_COST:
                costly = next(((r, k) for (r, k), c in _ORDER.items() if c > 0 and (r, k) != (self.name, key)), None)
                if costly is None:
                    break
                _evict(*costly)
            return value

    __setitem__ = put  # region[key] = value, as for a dict (keeps a value already cached)
    setdefault = put

    def touch(self, key) -> None:
        """Count a hit as a use (moves the entry to the recent end of the eviction order)."""
        with _LOCK:
            if (self.name, key) in _ORDER:
                _ORDER.move_to_end((self.name, key))

    def pop(self, key) -> None:
        with _LOCK:
            if key in self.data:
                _evict(self.name, key)

    def clear(self) -> None:
        with _LOCK:
            for k in list(self.data):
                _evict(self.name, k)

    def __len__(self) -> int:
        return len(self.data)


def _evict(name, key) -> None:
    reg = _REGIONS[name]
    value = reg.data.pop(key, None)
    _COST[0] -= _ORDER.pop((name, key), 0.0)
    if reg.on_evict is not None and value is not None:
        reg.on_evict(value)


def region(name: str, max_entries: int, on_evict=None) -> Region:
    """The region ``name`` (made on first use; the owner module keeps it)."""
    with _LOCK:
        reg = _REGIONS.get(name)
        if reg is None:
            reg = _REGIONS[name] = Region(name, max_entries, on_evict)
        return reg


def clear() -> None:
    """Forget every cached entry of every region, and every pooled integrator copy."""
    with _LOCK:
        for reg in _REGIONS.values():
            for k in list(reg.data):
                _evict(reg.name, k)
        _ORDER.clear()
        _COST[0] = 0.0
        _FREE.clear()


def info() -> dict:
    """``{region name: number of entries}``, plus ``"cost"`` (seconds of build time held) and ``"pooled"``
    (free integrator copies)."""
    with _LOCK:
        out = {name: len(reg.data) for name, reg in sorted(_REGIONS.items())}
        out["cost"] = _COST[0]
        out["pooled"] = sum(len(free) for _, free in _FREE.values())
        return out


# -- the pool of integrator copies ----------------------------------------------------------------------------------
def add_template(template, copies: int = 0) -> None:
    """Keep free copies of ``template`` (a cached integrator) from now on, starting with ``copies`` of them."""
    free = [copy.deepcopy(template) for _ in range(copies)]
    with _LOCK:
        _FREE.setdefault(id(template), (template, free))


def drop_template(template) -> None:
    """Forget the free copies of ``template`` (it left the cache)."""
    entry = _FREE.get(id(template))
    if entry is not None and entry[0] is template:
        with _LOCK:
            _FREE.pop(id(template), None)


def free_copies(template) -> list:
    """The list of free copies of ``template`` (a throwaway list when the template is not pooled)."""
    entry = _FREE.get(id(template))
    return entry[1] if entry is not None and entry[0] is template else []


def checkout(template):
    """(an integrator of the same kind as ``template`` that no other run is using, the list to release it to)."""
    free = free_copies(template)
    try:
        return free.pop(), free
    except IndexError:
        return copy.deepcopy(template), free


def release(ta, free) -> None:
    """Give a checked-out integrator back (kept while its template is pooled, at most :data:`MAX_FREE`)."""
    if len(free) < MAX_FREE:
        free.append(ta)
