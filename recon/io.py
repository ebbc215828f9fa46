"""File I/O every layer above shares: 8-bit images, OpenEXR, JSON, atomic writes.

Conventions:
  * 8-bit images are (H,W,3) uint8 RGB in memory (OpenCV's BGR stays inside this module);
  * EXR images are (H,W,3) float32 linear RGB, never gamma-encoded;
  * every writer here writes atomically: a hidden temporary file beside the target, renamed over
    it (os.replace) only once it is complete, so a crash or an error never leaves a half-written
    file; AtomicOutput does the same for the files of an output folder, AtomicFolder replaces
    a whole folder (keeping the user's own files in it); files and folders get the ordinary mode
    the umask gives (0644 and 0755 under umask 022), set in atomic_path, not mkstemp's 0600;
  * JSON is written as valid JSON (RFC 8259): non-finite floats (NaN, +-Infinity), which JSON
    cannot hold, are written as null. The conversion is deterministic (always null, wherever the
    value sits); a field that can be undetermined documents that null means "undetermined".
Errors name the file: `SceneError("<file>: <problem>")` (a ValueError).
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Iterator

import numpy as np


class SceneError(ValueError):
    """Bad input; the message names the file and the field or problem."""


_open3d_quiet = False


def open3d():
    """The open3d module, its console log limited to errors (set here, once, for the process):
    Open3D's warnings ("Read PLY failed", "appears to be a PointCloud") are not for users; the
    caller turns a failure into one clear error."""
    global _open3d_quiet
    import open3d as o3d

    if not _open3d_quiet:
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
        _open3d_quiet = True
    return o3d


# ---------------------------------------------------------------------------------------------
# Atomic writes

def current_umask() -> int:
    """The process's file-creation mask (e.g. 0o022), read without changing it where the system
    tells it (/proc/self/status on Linux); elsewhere set and restored at once."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path` (same suffix, so writers that pick the format from
    the name still work); on success it is given the umask's mode (0o666 & ~umask) and renamed
    over `path`, on an exception it is removed and `path` is left as it was. The parent folder is
    created if needed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".partial{path.suffix}")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())  # mkstemp makes it private (0600); the file gets the umask's mode
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_atomic(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call `write(tmp_path)` and rename the result over `path` (see atomic_path). Returns `path`."""
    with atomic_path(path) as tmp:
        write(tmp)
    return Path(path)


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


class AtomicFolder(AtomicOutput):
    """Replace the whole folder `out` by a new version, atomically; keep the user's own files.

    with AtomicFolder(out, ours) as stage: write the complete new version into stage. On success
    the files of the old `out` that the new version lacks and that `ours(name)` does not claim (the
    user's own files) move into the stage, the old folder is renamed aside and the stage renamed
    to `out` (so `out` never holds a mix of two versions, and files an earlier run wrote that this
    one does not are gone), then the old folder is removed. On an exception `out` is left as it
    was and nothing of the run remains. The new folder gets ordinary permissions (umask)."""

    def __init__(self, out: str | os.PathLike, ours: Callable[[str], bool]):
        super().__init__(out)
        self.ours = ours

    def __enter__(self) -> Path:
        stage = super().__enter__()
        os.chmod(stage, 0o777 & ~current_umask())  # mkdtemp makes it private; it becomes `out`
        return stage

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                old, kept = None, []
                try:
                    if self.out.exists():
                        for f in self.out.iterdir():
                            if not self.ours(f.name) and not (self.stage / f.name).exists():
                                os.replace(f, self.stage / f.name)
                                kept.append(f.name)
                        old = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.old-", dir=self.stage.parent))
                        os.replace(self.out, old / self.out.name)
                    os.replace(self.stage, self.out)
                except BaseException:  # put the old folder and the user's files back as they were
                    if old is not None and (old / self.out.name).exists():
                        os.replace(old / self.out.name, self.out)
                    for name in kept:
                        os.replace(self.stage / name, self.out / name)
                    if old is not None:
                        with contextlib.suppress(OSError):
                            os.rmdir(old)
                    raise
                if old is not None:
                    shutil.rmtree(old, ignore_errors=True)
        finally:
            shutil.rmtree(self.stage, ignore_errors=True)
        return False


def write_npz(path: str | os.PathLike, **arrays: np.ndarray) -> None:
    """numpy .npz archive of `arrays`, atomically (np.savez on a file object: it would append
    ".npz" to a temporary name)."""
    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    write_atomic(path, write)


# ---------------------------------------------------------------------------------------------
# 8-bit images

# What an image decoder says when the file ends early.
_TRUNCATED = ("Premature end", "Read Error", "truncated")


def _decoder_said(lines: list[str]) -> str:
    """The decoder's first complaint, as printable ASCII for one error line ('' if none)."""
    first = (lines or [""])[0]
    return "".join(c if c.isprintable() and c.isascii() else "?" for c in first).strip()[:100]


def read_image_rgb(path: str | os.PathLike) -> np.ndarray:
    """8-bit image file (PNG, JPEG, ...) -> (H,W,3) uint8 RGB, turned upright by its EXIF
    Orientation (a phone's JPEG; OpenCV's decoder applies it); grey images are expanded to three
    channels and alpha dropped. SceneError naming the file if it is missing, unreadable or not
    8-bit (a 16-bit image is refused rather than silently cut to 8 bits) or truncated (libjpeg
    would fill the missing rows with grey); the decoder's own stderr lines are held back and its
    first complaint becomes part of that one message."""
    import cv2

    from kernels.quiet import captured_stderr

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    with captured_stderr() as decoder:  # libpng/libjpeg print their complaints to the C-level stderr
        img = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    said = _decoder_said(decoder.lines())
    if img is None:
        raise SceneError(f"{path}: not a readable image{f' (decoder: {said})' if said else ''}")
    if any(t in said for t in _TRUNCATED):  # libjpeg fills the missing rows with grey and goes on
        raise SceneError(f"{path}: the image file is truncated (decoder: {said})")
    if img.dtype != np.uint8:
        raise SceneError(f"{path}: expected an 8-bit image, got {img.dtype}")
    return img[..., ::-1].copy()


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """(H,W,3) uint8 RGB (or (H,W) gray) to a PNG file, atomically; OSError naming the file."""
    import cv2

    img = np.asarray(rgb)
    img = np.ascontiguousarray(img[..., ::-1] if img.ndim == 3 else img)

    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), img):
            raise OSError(f"{path}: could not write PNG")

    write_atomic(path, write)


# ---------------------------------------------------------------------------------------------
# OpenEXR

def write_exr(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Linear float32 RGB (H,W,3) to an OpenEXR file (ZIP compression), atomically."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    data = {"RGB": np.ascontiguousarray(rgb, np.float32)}

    def write(tmp: Path) -> None:
        with OpenEXR.File(header, data) as f:
            f.write(str(tmp))

    write_atomic(path, write)


def read_exr(path: str | os.PathLike) -> np.ndarray:
    """OpenEXR RGB -> (H,W,3) float32; SceneError naming the file when it is missing, not an
    OpenEXR file, or lacks an R, G or B channel."""
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    try:
        with OpenEXR.File(str(path)) as f:
            ch = f.channels()
            if "RGB" in ch:
                return np.asarray(ch["RGB"].pixels, np.float32)
            missing = [c for c in "RGB" if c not in ch]
            if missing:
                raise SceneError(f"{path}: OpenEXR file has no {', '.join(missing)} channel "
                                 f"(channels: {', '.join(sorted(ch)) or 'none'})")
            return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGB"], -1)
    except SceneError:
        raise
    except Exception as e:  # OpenEXR raises its own types for non-EXR input
        raise SceneError(f"{path}: not a readable OpenEXR image ({e})") from None


# ---------------------------------------------------------------------------------------------
# JSON

def read_json(path: str | os.PathLike, error: type[Exception] | None = None):
    """Parsed JSON of `path`. A missing file raises FileNotFoundError and malformed JSON ValueError,
    both naming the file; with `error` (e.g. SceneError) both raise that instead."""
    path = Path(path)
    if not path.is_file():
        raise (error or FileNotFoundError)(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise (error or ValueError)(f"{path}: malformed JSON ({e})") from None


def json_field(d, key: str, where: str, path: str | os.PathLike):
    """d[key]; SceneError "<path>: missing field '<where><key>'" when `d` is not an object or lacks it."""
    if not isinstance(d, dict) or key not in d:
        raise SceneError(f"{path}: missing field '{where}{key}'")
    return d[key]


def _show(value, limit: int = 60) -> str:
    """`value` as short JSON-like text for a message: nan/inf as such, strings quoted, cut at `limit`."""
    def text(v) -> str:
        if isinstance(v, (list, tuple, np.ndarray)):
            return "[" + ", ".join(text(x) for x in v) + "]"
        if v is None:
            return "null"
        if isinstance(v, (bool, np.bool_)):
            return "true" if v else "false"
        if isinstance(v, (float, np.floating)):
            return f"{float(v):.6g}"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, dict):
            return "{...}"
        return str(v)

    t = text(value)
    return t if len(t) <= limit else t[:limit - 3] + "..."


def _describe(shape: tuple) -> str:
    """'a number', '3 numbers', '4x4 numbers' for an expected array shape."""
    if not shape:
        return "a number"
    if len(shape) == 1:
        return f"{shape[0]} numbers"
    return "x".join(str(n) for n in shape) + " numbers"


def _numbers_only(value) -> bool:
    """True when `value` is a number or a (nested) list of numbers: JSON numbers, not strings,
    booleans or null (np.asarray would turn "0.5" and true into 0.5 and 1.0)."""
    if isinstance(value, (list, tuple)):
        return all(_numbers_only(v) for v in value)
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "iuf"
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _not_a_number(value) -> str:
    """What the first entry of `value` that is no JSON number is: 'a string', 'null', ..."""
    if isinstance(value, (list, tuple)):
        for v in value:
            if not _numbers_only(v):
                return _not_a_number(v)
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return "a boolean"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, dict):
        return "an object"
    return f"a {type(value).__name__}"


def json_array(value, shape: tuple, where: str, path: str | os.PathLike) -> np.ndarray:
    """`value` as a float64 array of exactly `shape` with finite entries; SceneError naming the
    file, the field `where` and the value otherwise (a string, boolean or null where a number
    belongs is refused, never converted)."""
    shape = tuple(shape)
    if not _numbers_only(value):
        raise SceneError(f"{path}: field '{where}' must be {_describe(shape)}, got {_show(value)} "
                         f"({_not_a_number(value)} is not a number)")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):  # ragged lists
        raise SceneError(f"{path}: field '{where}' must be {_describe(shape)}, got {_show(value)}") from None
    if arr.shape != shape:
        raise SceneError(f"{path}: field '{where}' must be {_describe(shape)}, got {_show(value)}")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{path}: field '{where}' must be finite, got {_show(value)}")
    return arr


def json_bool(d: dict, key: str, where: str, path: str | os.PathLike, default: bool = False) -> bool:
    """d[key] as a JSON boolean (`default` when absent or null); SceneError naming the file and the
    field '<where><key>' for anything else (the string "false" is not false)."""
    v = d.get(key) if isinstance(d, dict) else None
    if v is None:
        return default
    if not isinstance(v, bool):
        raise SceneError(f"{path}: field '{where}{key}' must be true or false, got {_show(v)}")
    return v


def json_safe(o):
    """`o` with numpy scalars/arrays and Paths turned into JSON types and every non-finite float
    (NaN, +-Infinity) replaced by None (JSON null). Dict keys become strings as json does."""
    if isinstance(o, dict):
        return {(k if isinstance(k, str) else str(k)): json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, np.ndarray):
        return json_safe(o.tolist())
    if isinstance(o, (bool, np.bool_)):
        return bool(o)
    if isinstance(o, (int, np.integer)):
        return int(o)
    if isinstance(o, (float, np.floating)):
        v = float(o)
        return v if math.isfinite(v) else None
    if isinstance(o, Path):
        return str(o)
    if o is None or isinstance(o, str):
        return o
    raise TypeError(f"not JSON serialisable: {type(o)}")


def dumps_json(data, indent: int | None = None, sort_keys: bool = True) -> str:
    """Valid JSON text of `data` (see json_safe: non-finite floats become null)."""
    return json.dumps(json_safe(data), indent=indent, sort_keys=sort_keys, allow_nan=False)


def write_json(path: str | os.PathLike, data, indent: int = 2, sort_keys: bool = True) -> None:
    """Write `data` as valid JSON (non-finite floats become null), atomically."""
    text = dumps_json(data, indent=indent, sort_keys=sort_keys) + "\n"
    write_atomic(path, lambda tmp: tmp.write_text(text))
