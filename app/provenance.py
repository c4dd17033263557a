"""Which code made a state: a fingerprint of fbed's sources and Taichi's version, kept with checkpoints and run.h5
(attribute ``fbed_code``) and in the prepared-state cache's key, so a bed prepared by other code is not reused
as if this code had made it.

The fingerprint covers every module that can change what a run computes. It leaves out the packages that only
read what runs wrote (``analysis``, ``rcfd``: the post-processing; ``gui``: the renderer, which reads a snapshot;
``bench``: the benchmarks), so that editing a figure does not make a million-grain bed be prepared again."""
from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parent
READ_ONLY = ("analysis", "rcfd", "gui", "bench")  # subpackages that never change a run's state


def state_sources(root: pathlib.Path = PACKAGE) -> list[pathlib.Path]:
    """The sources the fingerprint covers, in a fixed order: every .py under ``root`` but READ_ONLY's."""
    return sorted(p for p in root.rglob("*.py")
                  if p.relative_to(root).parts[0] not in READ_ONLY and "__pycache__" not in p.parts)


def fingerprint(root: pathlib.Path = PACKAGE, taichi: str | None = None) -> str:
    """12 hex digits of SHA-1 over the sources' relative paths and bytes and Taichi's version (``taichi``:
    given, or read from the installed distribution's metadata, so nothing here imports Taichi)."""
    if taichi is None:
        try:
            taichi = importlib.metadata.version("taichi")
        except importlib.metadata.PackageNotFoundError:
            taichi = "none"
    h = hashlib.sha1(f"taichi {taichi}\n".encode())
    for p in state_sources(root):
        h.update(p.relative_to(root).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    return h.hexdigest()[:12]


@functools.lru_cache(maxsize=1)
def code_id() -> str:
    """This process's fingerprint (the sources are read once)."""
    return fingerprint()
