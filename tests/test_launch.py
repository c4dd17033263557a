"""The cached kernel launcher (app/sim/launch.py): a ``FastKernel`` gives what ``ti.kernel`` gives, skips Taichi's
per-call argument walk once it has a plan, and drops the plan whenever it would no longer be what Taichi does."""
import gc

import numpy as np
import pytest

pytestmark = pytest.mark.unit

ti = pytest.importorskip("taichi")

from app.sim import launch, runtime  # noqa: E402

Pack = ti.types.argpack(src=ti.types.ndarray(ndim=1), dst=ti.types.ndarray(ndim=1), scale=ti.f64, shift=ti.i32)


@ti.func
def _body(p: ti.template(), a, n, twice: ti.template()):
    for i in range(p.dst.shape[0]):
        v = p.scale * p.src[i] + a + n + p.shift
        if ti.static(twice):
            v *= 2.0
        p.dst[i] = v


def _make():
    def fill(p: Pack, a: ti.f64, n: ti.i32, twice: ti.template()):
        _body(p, a, n, twice)

    def total(x: ti.types.ndarray(ndim=1)) -> ti.f64:
        s = 0.0
        for i in range(x.shape[0]):
            s += x[i]
        return s

    return launch.kernel(fill), ti.kernel(fill), launch.kernel(total)


@pytest.fixture(scope="module")
def kernels():
    return _make()  # under the session's Taichi (float64, tests/conftest.py)


def _arr(values):
    a = ti.ndarray(ti.f64, shape=(len(values),))
    a.from_numpy(np.asarray(values, np.float64))
    return a


def _pack(n=4, scale=1.5, shift=3):
    return Pack(src=_arr(np.arange(n, dtype=float)), dst=_arr(np.zeros(n)), scale=scale, shift=shift)


def _counting(monkeypatch, kernel):
    """Count Taichi's own launches of ``kernel`` (its per-call argument walk)."""
    calls = []
    primal = kernel._primal
    orig = primal.launch_kernel

    def counted(*args):
        calls.append(1)
        return orig(*args)

    monkeypatch.setattr(primal, "launch_kernel", counted)
    return calls


def test_the_same_values_as_ti_kernel_and_new_scalars_every_call(kernels, monkeypatch):
    fast, plain, _ = kernels
    pf, pp = _pack(), _pack()
    walks = _counting(monkeypatch, fast)
    for a, n, twice in [(0.25, 1, False), (-2.0, 7, False), (0.5, -3, True), (1e-3, 0, True), (0.25, 1, False)]:
        fast(pf, a, n, twice)
        plain(pp, a, n, twice)
        np.testing.assert_array_equal(pf["dst"].to_numpy(), pp["dst"].to_numpy())
        expect = (1.5 * np.arange(4) + a + n + 3) * (2.0 if twice else 1.0)
        np.testing.assert_allclose(pf["dst"].to_numpy(), expect, rtol=1e-15, atol=1e-14)  # (order of the sums)
    # one walk per call signature (twice=False, twice=True; the first call of all is Taichi's own), none after
    assert len(walks) <= 3
    n0 = len(walks)
    for _ in range(5):
        fast(pf, 1.0, 2, False)
    assert len(walks) == n0


def test_a_pack_member_replaced_or_scalar_changed_is_seen(kernels):
    fast, _, _ = kernels
    p = _pack()
    fast(p, 0.0, 0, False)
    fast(p, 0.0, 0, False)  # a plan now
    other = _arr(np.zeros(4))
    p["dst"] = other
    p["scale"] = 10.0
    p["shift"] = -1
    fast(p, 0.0, 0, False)
    np.testing.assert_array_equal(other.to_numpy(), 10.0 * np.arange(4) - 1)  # small integers: exact


def test_a_new_pack_at_a_freed_address_is_not_taken_for_the_old_one(kernels):
    fast, _, _ = kernels
    seen, reused = set(), 0
    for k in range(200):  # until addresses were reused (the plan's weak reference must tell them apart)
        p = _pack(n=3 + k % 3, scale=float(k), shift=k)
        fast(p, 0.0, 0, False)
        fast(p, 0.0, 0, False)
        n = p["dst"].shape[0]
        np.testing.assert_array_equal(p["dst"].to_numpy(), k * np.arange(n) + k)
        reused += id(p) in seen
        seen.add(id(p))
        del p
        gc.collect()
        if reused >= 3:  # (each loop's gc.collect walks the worker's whole heap: 200 of them took 25-35 s on CI)
            break
    assert reused, "no address was reused: the case was not exercised"


def test_returns_and_errors_are_taichis(kernels):
    _, _, total = kernels
    x = _arr([1.0, 2.0, 3.5])
    assert total(x) == 6.5
    assert total(x) == 6.5  # from the plan
    assert total(np.array([1.0, 2.0])) == 3.0  # a numpy array: Taichi's own path
    fast, plain, _ = kernels
    p = _pack()
    fast(p, 0.0, 0, False)
    fast(p, 0.0, 0, False)
    with pytest.raises(Exception) as fe:
        fast(p, "a", 0, False)
    with pytest.raises(Exception) as pe:
        plain(p, "a", 0, False)
    assert type(fe.value) is type(pe.value)
    with pytest.raises(Exception) as fe:
        fast(p, 0.0, 1.5, False)  # a float for an i32
    assert "i32" in str(fe.value) or "int" in str(fe.value).lower()


def test_a_taichi_restart_drops_every_plan():
    fast, _, total = _make()
    p = _pack()
    fast(p, 1.0, 0, False)
    fast(p, 1.0, 0, False)
    with runtime.kept():  # the session's Taichi again afterwards
        runtime.init("cpu", "float32", 1)  # a new program: old arrays are gone, the kernels compile again
        x = ti.ndarray(ti.f32, shape=(3,))
        x.from_numpy(np.array([1.0, 2.0, 4.0], np.float32))
        assert total(x) == 7.0
        assert total(x) == 7.0
        q = Pack(src=x, dst=ti.ndarray(ti.f32, shape=(3,)), scale=2.0, shift=1)
        fast(q, 0.5, 1, True)
        fast(q, 0.5, 1, True)
        np.testing.assert_array_equal(q["dst"].to_numpy(), (2.0 * np.array([1.0, 2.0, 4.0]) + 2.5) * 2.0)


def _bed_step_state(plans_on: bool):
    """Four gas steps of a small bubbling-bed-like scene (cylinder vessel, cut cells, a bed with random gas
    fraction and drag, inflow, pressure outlet) with plans on or off; the face velocities and pressure."""
    from app.sim import gas
    from app.sim.geometry import CylinderWall

    shape, h = (6, 6, 10), 0.006
    cfg = gas.FlowConfig(shape=shape, h=h, rho=1.2, mu=1.8e-5, gravity=(0.0, 0.0, -9.81), tol=1e-8,
                          walls=(CylinderWall(center=(3 * h, 3 * h), radius=2.6 * h),), convection="maccormack",
                          bcs={"bottom": gas.velocity_inlet((0.0, 0.0, 0.4)), "top": gas.pressure_outlet(0.0)})
    rng = np.random.default_rng(7)
    with launch.plans(plans_on):
        s = gas.FlowSolver(cfg)
        for _ in range(4):
            eps = np.ones(shape)
            eps[:, :, :4] = 0.45 + 0.05 * rng.random((6, 6, 4))
            s.set_eps(eps)
            s.set_beta(np.where(eps < 1.0, 1.5e4, 0.0))
            info = s.step(1e-3)
        return s._get(s._st["vel"], s._nf), s.pressure(), info


def _entry_of(fast, pack):
    """The compiled-data entry of the plan that launches ``fast`` with ``pack``."""
    (plan,) = [pl for pl in fast._plans.values() if pl and any(ref() is pack for _, ref in pl.refs)]
    return fast._compiled[id(plan.t_kernel)]


def test_after_any_own_launch_a_plan_fetches_its_compiled_kernel_again(kernels):
    """Taichi 1.7.4 frees the compiled data it handed out for a kernel from the disk cache whenever it is fetched
    again, which its own launch does every time: after one, a plan must not launch what it fetched before
    (it did: a segfault in a two-grid gas test, 2026-12-03)."""
    fast, _, _ = kernels
    p = _pack(4)
    fast(p, 0.5, 1, False)
    fast(p, 0.5, 1, False)  # from the plan
    entry = _entry_of(fast, p)
    seen = entry[0]
    with launch.plans(False):
        fast(p, 0.5, 1, False)  # Taichi's own launch
    assert launch._own_launches[0] > seen
    fast(p, 0.25, 2, False)
    entry = _entry_of(fast, p)
    assert entry[0] == launch._own_launches[0]  # fetched again after the own launch
    np.testing.assert_allclose(p.dst.to_numpy(), 1.5 * np.arange(4) + 0.25 + 2 + 3)


def test_a_narrowed_view_shares_the_arrays_and_cannot_drop_a_read():
    """launch.narrowed / launch.view: a kernel given the view writes the full pack's own array; a type without a
    member the kernel reads does not compile; a name that is not a member is refused."""
    Dst = launch.narrowed(Pack, "dst", "shift")
    assert list(Dst.members) == ["dst", "shift"]
    full = _pack(3, shift=4)
    part = launch.view(Dst, full)

    def put(p: Dst):
        for i in range(p.dst.shape[0]):
            p.dst[i] = p.shift + i

    launch.kernel(put)(part)
    np.testing.assert_array_equal(full.dst.to_numpy(), [4.0, 5.0, 6.0])  # the full pack's dst itself

    def reads_src(p: Dst):
        for i in range(p.dst.shape[0]):
            p.dst[i] = p.src[i]

    with pytest.raises(Exception, match="src"):
        launch.kernel(reads_src)(part)
    with pytest.raises(KeyError, match="nothing"):
        launch.narrowed(Pack, "dst", "nothing")


def test_gas_steps_with_plans_are_bit_identical_to_taichis_own_launches():
    v_own, p_own, i_own = _bed_step_state(False)
    v_fast, p_fast, i_fast = _bed_step_state(True)
    assert i_own.pressure_iterations > 0 and np.abs(v_own).max() > 0.1  # the step did work
    np.testing.assert_array_equal(v_fast, v_own)
    np.testing.assert_array_equal(p_fast, p_own)
    assert i_fast == i_own
