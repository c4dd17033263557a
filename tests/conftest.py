"""Shared test set-up: Taichi runs on the CPU in float64 for the whole session.

float64 keeps conservation checks (1e-6 relative and tighter) about physics rather than
rounding; float32, the GPU default, is exercised through the CLI smoke tests.
"""
import os
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
REFERENCE = pathlib.Path(os.environ.get("FBED_REFERENCE", ROOT.parent / "shared" / "reference"))


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu64():
    from app.sim import runtime

    runtime.init(arch="cpu", precision="float64")
    yield


@pytest.fixture
def reference_dir():
    if not REFERENCE.is_dir():
        pytest.skip(f"reference data not found at {REFERENCE}")
    return REFERENCE
