"""On-disk cache of per-scene artefacts (the SH volume, the shaft hierarchy), keyed by their inputs.

An artefact is an object graph of numpy arrays, numbers, strings, lists, tuples, dicts and
instances of the project's own classes. It is stored as one .npz file (recon.io.write_npz,
atomic): every array under its own name, the rest as a JSON skeleton that refers to them. No
pickle: loading runs no code from the file; it only rebuilds instances of classes from the
project's packages (by module and name, without calling their constructors) and fills in their
attributes. Arrays the artefact shares with the engine (the transfers it was built from) are not
written; they are given back by identity on load (`shared`).

The key is a digest of exactly what the build reads, plus the source files of the code that
builds it (`code_digest`), so a change of that code is a miss, never a stale artefact.
"""
from __future__ import annotations

import hashlib
import importlib
import json
import logging
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

from recon.io import write_npz

log = logging.getLogger("photoar")
# packages whose classes an artefact may hold (rebuilt by name on load; nothing else is)
_PACKAGES = ("lighting.", "kernels.", "recon.", "app.")
_SKELETON = "__skeleton__"


def digest(*parts) -> str:
    """sha256 hex of parts: numpy arrays (dtype, shape and bytes), str, bytes, numbers, None,
    or lists/tuples of them."""
    h = hashlib.sha256()

    def add(x) -> None:
        if isinstance(x, np.ndarray) or isinstance(x, np.generic):
            a = np.ascontiguousarray(x)
            h.update(f"a{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        elif isinstance(x, (list, tuple)):
            h.update(f"l{len(x)}".encode())
            for y in x:
                add(y)
        elif isinstance(x, bytes):
            h.update(b"b%d:" % len(x) + x)
        else:
            s = repr(x) if isinstance(x, (int, float, bool, type(None))) else str(x)
            h.update(f"s{len(s)}:{s}".encode())

    for p in parts:
        add(p)
    return h.hexdigest()


def code_digest(*modules: str) -> str:
    """sha256 hex of the source files of `modules` (dotted names): the code that builds an artefact."""
    h = hashlib.sha256()
    for name in modules:
        h.update(name.encode())
        h.update(Path(importlib.import_module(name).__file__).read_bytes())
    return h.hexdigest()


class _Writer:
    def __init__(self, shared: dict[str, np.ndarray]):
        self.arrays: dict[str, np.ndarray] = {}
        self.shared = {id(a): k for k, a in shared.items()}

    def enc(self, x):
        if isinstance(x, np.ndarray):
            if id(x) in self.shared:
                return {"$shared": self.shared[id(x)]}
            if x.dtype.hasobject:
                raise TypeError("object arrays are not stored")
            name = f"a{len(self.arrays)}"
            self.arrays[name] = x
            return {"$array": name}
        if isinstance(x, np.generic):
            return {"$np": x.dtype.str, "v": x.item()}
        if x is None or isinstance(x, (bool, int, float, str)):
            return x
        if isinstance(x, list):
            return [self.enc(y) for y in x]
        if isinstance(x, tuple):
            return {"$tuple": [self.enc(y) for y in x]}
        if isinstance(x, dict):
            return {"$dict": [[self.enc(k), self.enc(v)] for k, v in x.items()]}
        cls = type(x)
        if not cls.__module__.startswith(_PACKAGES) or not hasattr(x, "__dict__"):
            raise TypeError(f"cannot store a {cls.__module__}.{cls.__qualname__}")
        return {"$obj": f"{cls.__module__}:{cls.__qualname__}",
                "attrs": {k: self.enc(v) for k, v in vars(x).items()}}


def _dec(x, arrays, shared):
    if isinstance(x, list):
        return [_dec(y, arrays, shared) for y in x]
    if not isinstance(x, dict):
        return x
    if "$array" in x:
        return arrays[x["$array"]]
    if "$shared" in x:
        return shared[x["$shared"]]
    if "$np" in x:
        return np.dtype(x["$np"]).type(x["v"])
    if "$tuple" in x:
        return tuple(_dec(y, arrays, shared) for y in x["$tuple"])
    if "$dict" in x:
        return {_dec(k, arrays, shared): _dec(v, arrays, shared) for k, v in x["$dict"]}
    module, _, name = x["$obj"].partition(":")
    if not module.startswith(_PACKAGES):
        raise ValueError(f"class {x['$obj']} is not the project's")
    cls = importlib.import_module(module)
    for part in name.split("."):
        cls = getattr(cls, part)
    obj = cls.__new__(cls)
    obj.__dict__.update({k: _dec(v, arrays, shared) for k, v in x["attrs"].items()})
    return obj


def save(path: str | Path, obj, shared: dict[str, np.ndarray] | None = None) -> None:
    """Write `obj` to `path` (.npz, atomically); arrays in `shared` are stored by name only."""
    w = _Writer(shared or {})
    skeleton = json.dumps(w.enc(obj))
    write_npz(path, **{_SKELETON: np.array(skeleton)}, **w.arrays)


def load(path: str | Path, shared: dict[str, np.ndarray] | None = None):
    """The object `save` wrote to `path` (no pickle); `shared` gives back the arrays stored by name."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != _SKELETON}
        skeleton = json.loads(str(z[_SKELETON]))
    return _dec(skeleton, arrays, shared or {})


def cached(path: Path | None, build: Callable[[], object], shared: dict[str, np.ndarray] | None = None,
           what: str = "artefact") -> tuple[object, bool]:
    """(artefact, hit): loaded from `path` when it is there and readable, else built (and saved
    when `path` is given). An unreadable file is rebuilt and overwritten, an artefact that cannot
    be stored is only not cached; neither is an error."""
    if path is not None and path.is_file():
        try:
            obj = load(path, shared)
            log.debug("%s: cache hit %s", what, path)
            return obj, True
        except (OSError, KeyError, ValueError, TypeError, AttributeError, ImportError, EOFError,
                zipfile.BadZipFile) as e:
            log.warning("%s: ignoring unreadable cache %s (%s)", what, path, e)
    obj = build()
    if path is not None:
        try:
            save(path, obj, shared)
        except TypeError as e:
            log.debug("%s: not cached (%s)", what, e)
    return obj, False
