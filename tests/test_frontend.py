"""The front end's memos (app/sim/frontend.py): the source-position messages and the sources they hand Taichi are
exactly those Taichi makes without them, so error messages and the IR (the offline cache's keys) do not change."""
import ast
import types

import pytest

pytestmark = pytest.mark.unit

ti = pytest.importorskip("taichi")

from app.sim import frontend, runtime  # noqa: E402
from taichi.lang import kernel_impl  # noqa: E402
from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext  # noqa: E402

MEMO = ASTTransformerContext.get_pos_info
ORIGINAL = MEMO.__wrapped__


@ti.func
def _shared(x: ti.template(), i):
    v = x[i] * 2.0
    if v > 1.0:
        v = 1.0
    for _ in range(2):
        v += 0.5
    return v


def _nodes(src: str):
    return [n for n in ast.walk(ast.parse(src)) if isinstance(n, (ast.stmt, ast.expr))]


def _ctx(src: str, name="f", offset=10):
    return types.SimpleNamespace(file="<fake>", func=types.SimpleNamespace(func=types.SimpleNamespace(__name__=name)),
                                 lineno_offset=offset, indent=0, src=src.splitlines())


def test_the_memo_is_installed_once_and_returns_taichis_own_message():
    frontend.install()  # again: nothing wrapped twice
    frontend.uninstall()
    assert ASTTransformerContext.get_pos_info is ORIGINAL and not hasattr(kernel_impl.getsourcelines, "_fbed_memo")
    frontend.install()
    assert ASTTransformerContext.get_pos_info is not ORIGINAL and hasattr(kernel_impl.getsourcelines, "_fbed_memo")
    frontend.uninstall()
    ASTTransformerContext.get_pos_info = MEMO  # the module's own memo back (install() would make a new one)
    frontend.install()
    assert ASTTransformerContext.get_pos_info is MEMO and MEMO.__wrapped__ is ORIGINAL
    assert not hasattr(ORIGINAL, "__wrapped__")
    assert kernel_impl.getsourcelines.__wrapped__.__name__ == "getsourcelines"
    src = "def f(a, b):\n    for i in range(a):\n        b[i] = a * i + (b[i]\n            - 1)\n    return b\n"
    ctx = _ctx(src)
    for node in _nodes(src):
        first = MEMO(ctx, node)
        assert first == ORIGINAL(ctx, node) == MEMO(ctx, node)  # a memo hit gives the same text again
        assert f"line {node.lineno + 10}" in first


def test_the_same_span_in_other_source_lines_is_not_mistaken():
    """Two sources alike in file, name, offset and every node's span, unlike in text: each gets its own message."""
    a, b = "def f(x):\n    return x + 1\n", "def f(y):\n    return y - 2\n"
    ca, cb = _ctx(a), _ctx(b)
    for na, nb in zip(_nodes(a), _nodes(b)):
        ma, mb = MEMO(ca, na), MEMO(cb, nb)
        assert ma == ORIGINAL(ca, na) and mb == ORIGINAL(cb, nb)
        assert (na.lineno, na.col_offset, na.end_col_offset) == (nb.lineno, nb.col_offset, nb.end_col_offset)
    assert MEMO(ca, _nodes(a)[-1]) != MEMO(cb, _nodes(b)[-1])


def test_compiling_kernels_gets_every_message_equal_to_taichis_own(monkeypatch):
    """Each message the transform asks for while two kernels inline one ti.func is compared with the one Taichi
    makes itself; the second kernel's share of the function's nodes comes from the memo."""
    runtime.init("cpu", "float64", threads=1)
    calls = []

    def checked(self, node):
        got = MEMO(self, node)
        assert got == ORIGINAL(self, node)
        calls.append(got)
        return got

    monkeypatch.setattr(ASTTransformerContext, "get_pos_info", checked)
    x = ti.ndarray(float, shape=(4,))
    x.fill(0.25)

    @ti.kernel
    def one(x: ti.types.ndarray(ndim=1)) -> ti.f64:
        s = 0.0
        for i in range(x.shape[0]):
            s += _shared(x, i)
        return s

    @ti.kernel
    def two(x: ti.types.ndarray(ndim=1)) -> ti.f64:
        s = 0.0
        for i in range(x.shape[0]):
            s += _shared(x, i) * 2.0
        return s

    assert one(x) == pytest.approx(4 * 1.5) and two(x) == pytest.approx(8 * 1.5)
    shared_lines = [m for m in calls if "in _shared:" in m]
    assert len(shared_lines) >= 2 * 5  # the function's statements, transformed at both call sites


def test_an_error_in_a_function_inlined_twice_names_its_own_line(monkeypatch):
    """A compile error in a ti.func is reported at the line of the bad expression, the same text with and without
    the memo (the memo holds that function's messages from the first kernel when the second fails)."""
    runtime.init("cpu", "float64", threads=1)

    @ti.func
    def bad(i):
        v = i + 1
        return v + undefined_name  # noqa: F821

    @ti.kernel
    def first() -> ti.i32:
        return bad(1)

    @ti.kernel
    def second() -> ti.i32:
        return bad(2)

    messages = []
    for kern in (first, second):
        with pytest.raises(ti.TaichiCompilationError) as err:
            kern()
        messages.append(str(err.value))
    monkeypatch.setattr(ASTTransformerContext, "get_pos_info", ORIGINAL)

    @ti.kernel
    def third() -> ti.i32:
        return bad(3)

    with pytest.raises(ti.TaichiCompilationError) as err:
        third()
    line = 1 + open(__file__).read().splitlines().index("        return v + undefined_name  # noqa: F821")
    for m in messages + [str(err.value)]:
        assert f"line {line}, in bad" in m and "undefined_name" in m
    tail = lambda m: m[m.index(f"line {line}, in bad"):]  # noqa: E731  (the kernel's own line comes first)
    assert tail(messages[0]) == tail(messages[1]) == tail(str(err.value))
