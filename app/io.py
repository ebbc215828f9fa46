"""Atomic output: a run's files appear in --out all together or not at all."""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np


def write_exr(path: Path, rgb: np.ndarray) -> None:
    """Linear float32 RGB (H,W,3) to an OpenEXR file (ZIP compression), never gamma-encoded."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb, np.float32)}) as f:
        f.write(str(path))


def read_exr(path: Path) -> np.ndarray:
    """OpenEXR RGB -> (H,W,3) float32."""
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.asarray(ch["RGB"].pixels, np.float32)
        missing = [c for c in "RGB" if c not in ch]
        if missing:
            raise ValueError(f"{path}: OpenEXR file has no {', '.join(missing)} channel "
                             f"(channels: {', '.join(sorted(ch)) or 'none'})")
        return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGB"], -1)


def write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise OSError(f"{path}: could not write PNG")


class AtomicOutput:
    """Stage files in a hidden folder beside `out`, move them in only on success.

    with AtomicOutput(out) as stage: write into stage / "name" ... ; on an exception nothing of
    the run is left in `out` (which is only created when the run succeeds).
    """

    def __init__(self, out: str | os.PathLike):
        self.out = Path(out)

    def __enter__(self) -> Path:
        parent = self.out.resolve().parent
        parent.mkdir(parents=True, exist_ok=True)
        self.stage = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.partial-", dir=parent))
        return self.stage

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                self.out.mkdir(parents=True, exist_ok=True)
                for f in sorted(self.stage.iterdir()):
                    os.replace(f, self.out / f.name)
        finally:
            shutil.rmtree(self.stage, ignore_errors=True)
        return False


def write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2, sort_keys=True, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")
