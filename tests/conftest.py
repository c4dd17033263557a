"""Shared test set-up: Taichi runs on the CPU in float64 for the whole session.

float64 keeps conservation checks (1e-6 relative and tighter) about physics rather than
rounding; float32, the GPU default, is exercised through the CLI smoke tests.
"""
import os
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
REFERENCE = pathlib.Path(os.environ.get("FBED_REFERENCE", ROOT.parent / "shared" / "reference"))


def _session_runtime():
    from app.sim import runtime

    # under pytest-xdist the cores are shared between the workers (CI: 2 cores, 2 workers, 1 thread each)
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    threads = max(1, (os.cpu_count() or 1) // workers) if workers > 1 else None
    runtime.init(arch="cpu", precision="float64", threads=threads)


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu64():
    _session_runtime()
    yield


@pytest.fixture
def session_runtime_after():
    """For a test that starts Taichi its own way (an in-process `fbed run` in float32): the session's float64
    CPU runtime is restored after it, so the tests that follow in the same worker run as they expect."""
    yield
    _session_runtime()


@pytest.fixture
def reference_dir():
    if not REFERENCE.is_dir():
        pytest.skip(f"reference data not found at {REFERENCE}")
    return REFERENCE


@pytest.fixture(scope="session")
def gui():
    """Skip renderer tests where no Vulkan device exists (probed in a child process: a failing GGUI
    start can abort the process). CI sets FBED_REQUIRE_RENDER=1 so there they fail instead of skipping."""
    import subprocess
    import sys

    probe = ("import taichi as ti; ti.init(arch=ti.cpu, log_level=ti.ERROR); "
             "w = ti.ui.Window('probe', (16, 16), show_window=False); w.get_canvas(); print('ok')")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    if "ok" not in r.stdout:
        why = (r.stderr.strip().splitlines() or ["no output"])[-1]
        if os.environ.get("FBED_REQUIRE_RENDER"):
            pytest.fail(f"GGUI cannot start offscreen ({why}): install mesa-vulkan-drivers")
        pytest.skip(f"no Vulkan device for GGUI ({why}); apt-get install mesa-vulkan-drivers")
    return True


TIERS = ("unit", "verification", "regression", "restart", "smoke", "stress", "bench")


def pytest_collection_modifyitems(config, items):
    """Every test belongs to a tier (a module's `pytestmark = pytest.mark.<tier>`), so that
    `python -m pytest -m unit` (or any tier) selects it; a module without one is an error, not a silent gap."""
    untiered = sorted({item.nodeid.split("::")[0] for item in items
                       if not any(m.name in TIERS for m in item.iter_markers())})
    if untiered:
        raise pytest.UsageError(f"tests without a tier ({', '.join(TIERS)}): {', '.join(untiered)}; "
                                "add `pytestmark = pytest.mark.<tier>` below the module's imports")
