"""Taichi 1.7.4's Python front end, made cheaper with the same output: two memos (installed on import).

Before a kernel is compiled, or looked up in the offline cache, Taichi turns its Python AST into IR, inlining
every ``ti.func`` it calls: a function's body is transformed again at each call site. For every AST node it
visits it formats a source-position message (``ASTTransformerContext.get_pos_info``: the line, and a line of
carets under the node, each wrapped by ``textwrap``), which is attached to the IR as debug information and
used in error messages; and for every function it reads the source again (``inspect.getsourcelines``).
Measured 2026-12-03 (CPU, cProfile, ``presets/boyce.toml`` started from a warm offline cache): of 12.6 s of
AST transform, 6.2 s went to those messages (110,000 of them for 78 kernels) and 1.0 s to reading sources.

- ``get_pos_info`` is memoized on everything its message is made of: the file, the function's name, first line
  and indent, the node's kind and span, the first line of its body, and the source lines it spans. The same
  message text for the same node, so error messages and the IR (and with it the offline cache's keys) are
  unchanged; only the formatting is not repeated.
- ``getsourcelines`` / ``getsourcefile`` are memoized per function object (a function's source does not change
  while the process runs; a function made anew is a new object).
"""
from __future__ import annotations

from taichi.lang import kernel_impl
from taichi.lang.ast import ast_transformer_utils as _utils

_Context = _utils.ASTTransformerContext
_BODY_FIRST = ("For", "While", "FunctionDef", "If")  # the kinds whose message stops before their body
_SOURCE_READERS = ("getsourcelines", "getsourcefile")  # kernel_impl's own names for them


def _memo_pos_info(original):
    memo: dict = {}

    def get_pos_info(self, node):
        kind = node.__class__.__name__
        lineno = node.lineno
        body = node.body[0].lineno if kind in _BODY_FIRST and getattr(node, "body", None) else 0
        key = (self.file, self.func.func.__name__, self.lineno_offset, self.indent, kind, lineno, node.col_offset,
               node.end_lineno, node.end_col_offset, body, tuple(self.src[lineno - 1:max(node.end_lineno, lineno)]))
        msg = memo.get(key)
        if msg is None:
            msg = memo[key] = original(self, node)
        return msg

    get_pos_info.__wrapped__ = original
    get_pos_info._fbed_memo = memo
    return get_pos_info


def _memo_per_function(original):
    memo: dict = {}

    def lookup(obj):
        try:
            return memo[obj]
        except KeyError:
            value = memo[obj] = original(obj)
            return value
        except TypeError:  # not hashable: as Taichi does
            return original(obj)

    lookup.__wrapped__ = original
    lookup._fbed_memo = memo
    return lookup


def install() -> None:
    """Install the memos (once; importing this module does it)."""
    if not hasattr(_Context.get_pos_info, "_fbed_memo"):
        _Context.get_pos_info = _memo_pos_info(_Context.get_pos_info)
    for name in _SOURCE_READERS:
        fn = getattr(kernel_impl, name)
        if not hasattr(fn, "_fbed_memo"):
            setattr(kernel_impl, name, _memo_per_function(fn))


def uninstall() -> None:
    """Taichi's own front end again (for A/B benchmarks: ``benchmarks/startup_cost.py``)."""
    if hasattr(_Context.get_pos_info, "_fbed_memo"):
        _Context.get_pos_info = _Context.get_pos_info.__wrapped__
    for name in _SOURCE_READERS:
        fn = getattr(kernel_impl, name)
        if hasattr(fn, "_fbed_memo"):
            setattr(kernel_impl, name, fn.__wrapped__)


install()
