"""Warp initialisation and device choice shared by every kernel wrapper."""
from __future__ import annotations

import os

import warp as wp

_initialised = False


def init() -> None:
    """Initialise Warp once (kernels/__init__ silences its banner)."""
    global _initialised
    if not _initialised:
        wp.init()
        _initialised = True


def device(name: str | None = None) -> str:
    """Resolve a device name: explicit argument, else $PHOTOAR_DEVICE, else "cpu"."""
    init()
    name = name or os.environ.get("PHOTOAR_DEVICE", "cpu")
    if name.startswith("cuda") and not wp.is_cuda_available():
        raise RuntimeError(f"device {name!r} requested but no CUDA device is available")
    return name
