"""Per-mesh caches and scratch buffers: the one mechanism for data derived from a mesh's connectivity.

Every :class:`~lacore.geometry.topology.MeshTopology` owns a :class:`DerivedCache`
(``topology.cache``).  Modules that derive target-independent data from the
connectivity (sparsity patterns, stencils, spanning-tree tables, symbolic
factorizations, reconstruction contexts) store it there under a key in ONE
namespace::

    (owner, name, *params)

``owner`` is the ``__name__`` of the module that computes the value (so two
modules never collide and :meth:`DerivedCache.clear` can drop one module's
entries), ``name`` says what it is, ``params`` (hashable) distinguish variants
(e.g. the energy block kind).  Values are computed on first use
(:meth:`DerivedCache.get`); NumPy arrays are made read-only.  The connectivity
of a topology never changes, so entries stay valid for its lifetime;
:meth:`DerivedCache.clear` frees memory (or makes a benchmark measure a cold
start).

:func:`scratch` hands out reusable float64 work buffers (per mesh, per thread)
and :func:`carve` cuts one buffer into consecutive views.
"""

import math
import threading

import numpy as np

__all__ = ["DerivedCache", "scratch", "carve"]


class DerivedCache:
    """A memo of values derived from one mesh, keyed by ``(owner, name, *params)`` (module docstring)."""

    def __init__(self):
        self._data = {}
        self._lock = threading.Lock()

    @staticmethod
    def _check_key(key):
        if not (isinstance(key, tuple) and len(key) >= 2 and isinstance(key[0], str) and isinstance(key[1], str)):
            raise TypeError(f"cache keys are tuples (owner module, name, *params), got {key!r}")

    def __getstate__(self):
        """A pickled cache arrives empty: derived data and solver objects are rebuilt in the process that uses them
        (e.g. a :mod:`lacore.parallel` worker receiving a topology)."""
        return {}

    def __setstate__(self, state):
        self.__init__()

    def get(self, key, compute):
        """The value under ``key``, computed by ``compute()`` on first use (arrays made read-only)."""
        try:
            return self._data[key]
        except KeyError:
            pass
        self._check_key(key)
        value = compute()
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
        with self._lock:  # two threads computing the same entry keep the first value
            return self._data.setdefault(key, value)

    def peek(self, key, default=None):
        """The value under ``key`` if present, else ``default`` (nothing is computed)."""
        return self._data.get(key, default)

    def put(self, key, value):
        """Store ``value`` under ``key`` (replacing an entry; arrays made read-only)."""
        self._check_key(key)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
        with self._lock:
            self._data[key] = value

    def discard(self, key):
        """Drop the entry under ``key`` if present."""
        with self._lock:
            self._data.pop(key, None)

    def __contains__(self, key):
        return key in self._data

    def __len__(self):
        return len(self._data)

    def keys(self, owner=None):
        """The keys held (of one ``owner`` module if given)."""
        return [k for k in self._data if owner is None or k[0] == owner]

    def clear(self, owner=None):
        """Drop every entry (or those of one ``owner`` module, e.g. ``"lacore.reconstruction.context"``)."""
        with self._lock:
            if owner is None:
                self._data.clear()
            else:
                for k in [k for k in self._data if k[0] == owner]:
                    del self._data[k]


def scratch(topology, name, n):
    """A float64 scratch buffer of ``n`` entries, cached on the topology per thread.

    The buffers are reused across calls (no page faults for fresh memory) and
    never returned to the caller of a public function: every result is copied
    out of them.  Callers bound them by a block size, so they stay small even
    for large meshes.
    """
    store = topology.cache.get((__name__, "scratch"), dict)
    key = (threading.get_ident(), name)
    buf = store.get(key)
    if buf is None or buf.size < n:
        buf = store[key] = np.empty(n)
    return buf[:n]


def carve(buf, *shapes):
    """Consecutive C-contiguous views of ``buf`` with the given shapes (a list, one view per shape)."""
    views, pos = [], 0
    for shape in shapes:
        size = math.prod(shape)
        views.append(buf[pos:pos + size].reshape(shape))
        pos += size
    return views
