"""A test double around the device's read points: counts kernel launches and host reads.

``with KernelCounter(modules) as kc: ...`` replaces every Taichi kernel defined in ``modules``
by a wrapper that counts its launches, and counts as one *host read* each launch of a kernel
that returns a value (the host waits for it), each ``to_numpy()`` of a field or ndarray and each
element read of one from Python scope (``field[i]``), and the ndarray arguments each launch sets (every
ndarray member of an argument pack counts: Taichi 1.7.4 sets them all, read or not, ~3 us each on the host).
Everything is restored on exit.
Used by the gas-step test and by benchmarks/gas_counts.py.
"""
from __future__ import annotations

import collections
import importlib


def _ndarrays(args) -> int:
    """Ndarray arguments a launch with these positional arguments sets (top level and pack members)."""
    nd = importlib.import_module("taichi.lang._ndarray").Ndarray
    pack = importlib.import_module("taichi.lang.argpack").ArgPack
    n = 0
    for a in args:
        if isinstance(a, nd):
            n += 1
        elif isinstance(a, pack):
            n += _ndarrays(a._ArgPack__entries.values())
    return n


def _classes():
    nd = importlib.import_module("taichi.lang._ndarray")
    fd = importlib.import_module("taichi.lang.field")
    mx = importlib.import_module("taichi.lang.matrix")
    return (nd.Ndarray, nd.ScalarNdarray, fd.Field, fd.ScalarField, mx.MatrixField, mx.MatrixNdarray,
            mx.VectorNdarray)


class KernelCounter:
    def __init__(self, modules):
        self.modules = list(modules)
        self.launches = 0
        self.reads = 0
        self.ndarray_args = 0
        self.by_kernel = collections.Counter()
        self.reads_by = collections.Counter()
        self._saved = []

    def reset(self) -> None:
        self.launches = 0
        self.reads = 0
        self.ndarray_args = 0
        self.by_kernel.clear()
        self.reads_by.clear()

    def _wrap_kernel(self, name, k):
        returns = k._primal.return_type is not None
        counter = self

        def wrapped(*args, **kw):
            counter.launches += 1
            counter.by_kernel[name] += 1
            counter.ndarray_args += _ndarrays(args)
            if returns:
                counter.reads += 1
                counter.reads_by[name] += 1
            return k(*args, **kw)

        wrapped._is_wrapped_kernel = True
        wrapped._primal = k._primal
        return wrapped

    def _wrap_read(self, cls, attr, fn):
        counter = self

        def wrapped(obj, *args, **kw):
            counter.reads += 1
            counter.reads_by[f"{cls.__name__}.{attr}"] += 1
            return fn(obj, *args, **kw)

        return wrapped

    def __enter__(self):
        for mod in self.modules:
            for name, obj in list(vars(mod).items()):
                if callable(obj) and getattr(obj, "_is_wrapped_kernel", False) and not getattr(
                        obj, "_is_classkernel", False):
                    self._saved.append((mod, name, obj))
                    setattr(mod, name, self._wrap_kernel(f"{mod.__name__.rsplit('.', 1)[-1]}.{name}", obj))
        for cls in _classes():
            for attr in ("to_numpy", "__getitem__"):
                if attr in cls.__dict__:
                    fn = cls.__dict__[attr]
                    self._saved.append((cls, attr, fn))
                    setattr(cls, attr, self._wrap_read(cls, attr, fn))
        return self

    def __exit__(self, *exc):
        for owner, name, obj in reversed(self._saved):
            setattr(owner, name, obj)
        self._saved.clear()
        return False
