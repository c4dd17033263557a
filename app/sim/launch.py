"""Kernel launches without Taichi 1.7.4's per-call argument walk: :func:`kernel`, a drop-in for ``@ti.kernel``.

Each call of a Taichi 1.7.4 kernel walks its arguments in Python twice (``Kernel.__call__``: the template
mapper's key, then ``launch_kernel``'s recursive setter), about 100-200 us for a kernel over a few argument
packs, while the launch itself costs 10-70 us. The gas step launches 45-160 kernels, so on a GPU the host, not
the device, set the step's pace. A :class:`FastKernel` makes that walk once per *call signature* (the same
argument objects, the same template values) and keeps a plan: the compiled kernel, the argument packs' and
ndarrays' handles with their slots, and a setter per scalar. A call then builds a fresh launch context from
the plan (a context cannot be reused: the CUDA launcher leaves device pointers in it), sets the scalars and
launches.

The plan is used only while it is exactly what Taichi would do: every object it holds is the one passed
(checked by weak reference, so a new object at a recycled address is not mistaken for it), every ndarray
member of a pack is still the one the plan holds, and the Taichi program is the one it was made under
(``ti.init`` again drops every plan). Anything else, and any argument kind it does not know (numpy arrays,
matrices as arguments, nested packs, gradients, keyword arguments), goes through Taichi's own call, which
compiles, checks and raises as before.
"""
from __future__ import annotations

import contextlib
import functools
import operator
import weakref

import numpy as np
import taichi as ti
from taichi.lang import impl, kernel_impl, runtime_ops
from taichi.lang._ndarray import Ndarray
from taichi.lang.argpack import ArgPack, ArgPackType
from taichi.lang.exception import handle_exception_from_cpp
from taichi.types import ndarray_type, primitive_types
from taichi.types.annotations import template
from taichi.types.utils import is_signed
from taichi.lang.util import cook_dtype

from . import frontend  # noqa: F401  (the front end's memos: every module with kernels imports this one)

_REAL = (float, int, np.floating, np.integer)
_INT = (int, np.integer)
_PRIMITIVE = (bool, int, float, str, type(None))
_TEMPLATE, _OBJECT, _SCALAR = 0, 1, 2
#: plans kept per kernel before the oldest are dropped (a solver has a handful of call signatures)
MAX_PLANS = 64


# Taichi's own launches so far. Why they matter: Taichi 1.7.4 hands out a kernel's compiled data by reference, and
# for a kernel read from the offline cache on disk it reads the file again at every ``compile_kernel`` call and
# frees the copy it handed out before (KernelCompilationManager::try_load_cached_kernel). Taichi's own launch calls
# it every time; a plan keeps the reference, so after any launch of Taichi's own (a first call, a fallback, a plain
# ti.kernel) every plan fetches its compiled data again once. Our own fetches are one per Taichi kernel instance
# (shared by all its plans), so they free nothing a plan still holds.
_own_launches = [0]
_taichi_launch = kernel_impl.Kernel.launch_kernel


def _counted_launch(self, t_kernel, *args):
    _own_launches[0] += 1
    return _taichi_launch(self, t_kernel, *args)


kernel_impl.Kernel.launch_kernel = _counted_launch


class _Slow(Exception):
    """An argument the plan does not handle: the call goes through Taichi's own path."""


class _Plan:
    __slots__ = ("prog", "t_kernel", "refs", "packs", "members", "ndarrays", "scalars")

    def valid(self, args, prog) -> bool:
        if prog is not self.prog:
            return False
        for pos, ref in self.refs:
            if ref() is not args[pos]:
                return False
        for pos, names, held in self.members:  # weak references: a plan keeps no array alive
            entries = args[pos]._ArgPack__entries
            if not all(map(operator.is_, map(operator.call, held), map(entries.__getitem__, names))):
                return False
        return True


class FastKernel:
    """A ``ti.kernel`` whose launches reuse a plan of its argument handling (see the module's text).

    Behaves as the kernel: same arguments, same result, same errors (those come from Taichi's own path, which
    a call the plan cannot serve takes). ``_primal`` is Taichi's kernel object (for test doubles).
    """

    #: False: every call is Taichi's own (:func:`plans`; for A/B benchmarks and tests)
    plans_on = True

    def __init__(self, func):
        self._kernel = ti.kernel(func)
        # Taichi's marks of a kernel, on the instance (not the class: a module that imports FastKernel holds no
        # kernel for tests/kernel_counter.py to find)
        self._is_wrapped_kernel = True
        self._is_classkernel = False
        self._primal = self._kernel._primal
        functools.update_wrapper(self, func)  # its name, module and text are the function's
        self._plans: dict = {}
        # per Taichi kernel instance (id): [Taichi's own launches when fetched, its compiled data, the instance]
        self._compiled: dict = {}
        self._external = False  # set once it is given a numpy array: then every call is Taichi's own
        self._kinds = None  # per argument: True for a template, False otherwise (read at the first call)

    def __call__(self, *args, **kwargs):
        if kwargs or self._external or not FastKernel.plans_on:
            return self._kernel(*args, **kwargs)
        kinds = self._kinds
        if kinds is None:
            ret = self._kernel(*args)  # the first call compiles and checks the arguments
            self._kinds = [_TEMPLATE if isinstance(a.annotation, template) else
                           _OBJECT if isinstance(a.annotation, (ArgPackType, ndarray_type.NdarrayType)) else _SCALAR
                           for a in self._primal.arguments]
            return ret
        if len(args) != len(kinds):
            return self._kernel(*args)
        # the key: a template's value where it is a plain value, the identity of every object, nothing of a scalar
        key = tuple(None if t == _SCALAR else (a if t == _TEMPLATE and type(a) in _PRIMITIVE else id(a))
                    for a, t in zip(args, kinds))
        prog = impl.get_runtime().prog
        plan = self._plans.get(key)
        if plan is None or (plan is not False and not plan.valid(args, prog)):
            plan = self._make_plan(args, prog)
            if len(self._plans) >= MAX_PLANS:
                self._plans.pop(next(iter(self._plans)))
            self._plans[key] = plan
            if plan is False:
                return self._kernel(*args)
        elif plan is False:
            return self._kernel(*args)
        return self._launch(plan, args, prog)

    # ------------------------------------------------------------------ the plan
    def _make_plan(self, args, prog):
        """The plan for these arguments, or False where one argument needs Taichi's own path."""
        k = self._primal
        try:
            key = k.ensure_compiled(*args)  # compiles this instance if new (the key Taichi's own call uses)
            plan = _Plan()
            plan.prog = prog
            plan.t_kernel = k.compiled_kernels[key]
            plan.refs, plan.packs, plan.members, plan.ndarrays, plan.scalars = [], [], [], [], []
            later = []  # ndarrays inside packs: Taichi gives them the slots after the top-level arguments
            slot = 0
            for pos, (a, meta) in enumerate(zip(args, k.arguments)):
                anno = meta.annotation
                if isinstance(anno, template):
                    if type(a) not in _PRIMITIVE:
                        plan.refs.append((pos, weakref.ref(a)))  # TypeError (no weak reference): slow path
                    continue
                if isinstance(anno, (ArgPackType, ndarray_type.NdarrayType)) and not isinstance(a, (ArgPack, Ndarray)):
                    self._external = True  # an external (numpy) array: a new object at every call
                    raise _Slow
                if isinstance(anno, ArgPackType):
                    if not isinstance(a, ArgPack):
                        raise _Slow
                    entries = a._ArgPack__entries
                    names, held = [], []
                    for name, m_anno in anno.members.items():
                        v = entries[name]
                        if isinstance(m_anno, ArgPackType):
                            raise _Slow  # nested packs: Taichi's own path
                        if isinstance(m_anno, ndarray_type.NdarrayType):
                            if not isinstance(v, Ndarray) or v.grad is not None:
                                raise _Slow
                            later.append(v.arr)
                            names.append(name)
                            held.append(weakref.ref(v))
                    plan.refs.append((pos, weakref.ref(a)))
                    plan.members.append((pos, tuple(names), tuple(held)))
                    plan.packs.append(((slot,), a._ArgPack__argpack))
                elif isinstance(anno, ndarray_type.NdarrayType):
                    if not isinstance(a, Ndarray) or a.grad is not None:
                        raise _Slow
                    plan.refs.append((pos, weakref.ref(a)))
                    plan.ndarrays.append(((slot,), a.arr))
                elif id(anno) in primitive_types.real_type_ids:
                    plan.scalars.append((pos, (slot,), 0))
                elif id(anno) in primitive_types.integer_type_ids:
                    plan.scalars.append((pos, (slot,), 1 if is_signed(cook_dtype(anno)) else 2))
                else:
                    raise _Slow  # matrices, structs, textures, ...
                slot += 1
            n_top = slot
            plan.ndarrays.extend(((n_top + j,), arr) for j, arr in enumerate(later))
            return plan
        except (_Slow, TypeError):
            return False

    def _compiled_data(self, plan: _Plan, prog):
        """The plan's compiled kernel, fetched again after any launch of Taichi's own (see ``_own_launches``)."""
        entry = self._compiled.get(id(plan.t_kernel))
        if entry is None or entry[0] != _own_launches[0] or entry[2] is not plan.t_kernel:
            data = prog.compile_kernel(prog.config(), prog.get_device_caps(), plan.t_kernel)
            entry = self._compiled[id(plan.t_kernel)] = [_own_launches[0], data, plan.t_kernel]
        return entry[1]

    def _launch(self, plan: _Plan, args, prog):
        ctx = plan.t_kernel.make_launch_context()
        for idx, pack in plan.packs:
            ctx.set_arg_argpack(idx, pack)
        for idx, arr in plan.ndarrays:
            ctx.set_arg_ndarray(idx, arr)
        for pos, idx, kind in plan.scalars:
            v = args[pos]
            if kind == 0:
                if not isinstance(v, _REAL):
                    return self._kernel(*args)  # Taichi's own path raises its error
                ctx.set_arg_float(idx, float(v))
            else:
                if not isinstance(v, _INT):
                    return self._kernel(*args)
                if kind == 1:
                    ctx.set_arg_int(idx, int(v))
                else:
                    ctx.set_arg_uint(idx, int(v))
        k = self._primal
        try:
            prog.launch_kernel(self._compiled_data(plan, prog), ctx)
        except Exception as e:  # as Taichi's own launch reports it
            raise handle_exception_from_cpp(e) from None
        ret_dt = k.return_type
        if ret_dt is None:
            if k.has_print:
                runtime_ops.sync()
            return None
        runtime_ops.sync()
        ret = [k.construct_kernel_ret(ctx, t, (i,)) for i, t in enumerate(ret_dt)]
        return ret[0] if len(ret_dt) == 1 else ret


@contextlib.contextmanager
def plans(on: bool):
    """Within the block, launches from plans (True, the default) or every call Taichi's own (False)."""
    before = FastKernel.plans_on
    FastKernel.plans_on = bool(on)
    try:
        yield
    finally:
        FastKernel.plans_on = before


def narrowed(full: ArgPackType, *names: str) -> ArgPackType:
    """The argpack type of ``full``'s members ``names`` only, for a kernel launched many times a step that reads
    no other: Taichi 1.7.4 sets every ndarray member of a pack at every launch, ~3 us each on the host (CPU,
    2026-12-03), whether the kernel reads it or not. A member the kernel reads but the type lacks fails the
    kernel's compilation, so a narrowed type cannot drop a read silently."""
    missing = [n for n in names if n not in full.members]
    if missing:
        raise KeyError(f"narrowed: {missing} not members of the pack ({list(full.members)})")
    return ti.types.argpack(**{n: full.members[n] for n in names})


def view(pack_type: ArgPackType, pack: ArgPack) -> ArgPack:
    """A ``pack_type`` (a :func:`narrowed` type) holding ``pack``'s own arrays and values: nothing copied, so a
    kernel given the view reads and writes the arrays of ``pack``."""
    return pack_type(**{n: pack[n] for n in pack_type.members})


def kernel(func) -> FastKernel:
    """``@launch.kernel`` in place of ``@ti.kernel``: the same kernel, launched from a cached plan."""
    return FastKernel(func)
