"""Device buffers allocated once at capacity, with a host mirror for uploads and downloads.

A per-frame upload writes into `host` (a numpy view) and calls `push`; nothing is allocated
after construction. On the CPU the mirror is the device array itself (zero copy); on CUDA it is
a pinned host array and push/pull copy the first `count` elements (wp.copy, no temporaries).
"""
from __future__ import annotations

import numpy as np
import warp as wp


# Buffer.view's views kept per buffer (0: a new view every call, as before dragpy110)
VIEW_CACHE = 64


class Buffer:
    """A Warp array `dev` of fixed shape and its host mirror `host` (numpy, same shape; vector
    dtypes add a trailing axis)."""

    def __init__(self, shape: int | tuple[int, ...], dtype, device: str, fill=None):
        self.device = device
        self.dev = wp.zeros(shape, dtype=dtype, device=device)
        self._cpu = wp.get_device(device).is_cpu
        self._mirror = self.dev if self._cpu else wp.zeros(shape, dtype=dtype, device="cpu", pinned=True)
        self.host: np.ndarray = self._mirror.numpy()  # a view: writes go straight into the mirror
        self._views: dict[tuple[int, ...], wp.array] = {}  # view(): the leading blocks handed out, by shape
        if fill is not None:
            self.host[...] = fill
            self.push()

    @property
    def capacity(self) -> int:
        return self.dev.shape[0]

    def push(self, count: int | None = None) -> wp.array:
        """Copy the host mirror's first `count` rows (default all) to the device; returns `dev`."""
        if not self._cpu and count != 0:
            wp.copy(self.dev, self._mirror, count=self._elements(count))
        return self.dev

    def pull(self, count: int | None = None) -> np.ndarray:
        """The device's first `count` rows (default all) as a numpy view of the host mirror
        (valid until the next pull or upload)."""
        n = self.dev.shape[0] if count is None else count
        if not self._cpu and n != 0:
            wp.copy(self._mirror, self.dev, count=self._elements(count))
            wp.synchronize_device(self.device)
        return self.host[:n]

    def upload(self, values: np.ndarray) -> int:
        """Write `values` (n rows, n <= capacity) into the first rows and push them; returns n."""
        n = len(values)
        if n > self.capacity:
            raise ValueError(f"{n} rows exceed the buffer's capacity {self.capacity}")
        self.host[:n] = values
        self.push(n)
        return n

    def view(self, shape: tuple[int, ...]) -> wp.array:
        """The device view of `dev`'s leading block of `shape` (no memory allocated), kept by shape: making a
        Warp view costs ~10-30 us of interpreter time (wp.array.__getitem__), and a frame's uploads ask the same
        few shapes again (at most VIEW_CACHE kept; the cache is emptied when full)."""
        v = self._views.get(shape) if VIEW_CACHE else None
        if v is None:
            v = _rows(self.dev, shape)
            if VIEW_CACHE:
                if len(self._views) >= VIEW_CACHE:
                    self._views.clear()
                self._views[shape] = v
        return v

    def _elements(self, rows: int | None) -> int:
        """Elements in `rows` leading rows (0: the whole array, wp.copy's convention)."""
        if rows is None:
            return 0
        per_row = int(np.prod(self.dev.shape[1:])) if self.dev.ndim > 1 else 1
        return rows * per_row


class Workspace:
    """Named Buffers kept by one call site of a kernel wrapper (e.g. transfer_matrix's inputs and
    outputs), reused from call to call so that a frame allocates nothing once they exist.

    The wrappers given a Workspace work in blocks of at most `rows` points (rays, receivers) and
    `sources` patches per launch, so its buffers have a fixed capacity whatever the frame asks
    for; inputs of a size fixed per object shape (its triangles) are allocated on the first call
    and again only when a later request outgrows them (at 1.5x). Not shared between threads: a
    wrapper that runs two launches at once uses one name per launch ("points0", "points1")."""

    def __init__(self, rows: int = 16384, sources: int = 1024) -> None:
        self.rows = rows
        self.sources = sources
        self._buffers: dict[str, Buffer] = {}
        self._subs: dict[str, Workspace] = {}

    def sub(self, name: str) -> Workspace:
        """The buffers of a second kernel at the same call site (e.g. a far-field sum beside the exact
        one), of the same block sizes, kept beside this one's."""
        if name not in self._subs:
            self._subs[name] = Workspace(self.rows, self.sources)
        return self._subs[name]

    def buffer(self, name: str, rows: int, dtype, device: str, cols: tuple[int, ...] = ()) -> Buffer:
        """The Buffer `name` holding at least `rows` rows of shape `cols` (and at least the
        requested size along each of `cols`) of `dtype` on `device`."""
        b = self._buffers.get(name)
        if b is not None and b.device == device and b.dev.dtype == dtype and b.dev.ndim == 1 + len(cols):
            have = b.dev.shape
            if have[0] >= rows and all(h >= c for h, c in zip(have[1:], cols)):
                return b
            # it outgrew its buffer: leave room for the next growth (1.5x along what grew)
            rows = have[0] if have[0] >= rows else int(1.5 * rows)
            cols = tuple(h if h >= c else int(1.5 * c) for h, c in zip(have[1:], cols))
        b = self._buffers[name] = Buffer((max(rows, 1), *cols), dtype, device)
        return b

    def upload(self, name: str, values: np.ndarray, dtype, device: str, capacity: int = 0,
               col_capacity: int = 0) -> wp.array:
        """`values` (n rows) copied into buffer `name` (at least max(n, capacity) rows and, for 2-d or
        wider values, at least max(m, col_capacity) columns, m = values.shape[1]: columns that vary from
        call to call; both grow 1.5x past what a call outgrew, as `buffer` does; trailing shape from
        `dtype`'s length when a vector type) and pushed; returns the device view of its leading
        block of values' shape."""
        values = np.asarray(values)
        n = len(values)
        cols = values.shape[1:-1] if _is_vector(dtype) else values.shape[1:]
        if cols and col_capacity > cols[0]:
            cols = (col_capacity, *cols[1:])
        b = self.buffer(name, max(n, capacity), dtype, device, cols)
        b.host[(slice(0, n), *(slice(0, k) for k in values.shape[1:]))] = values
        b.push(n)
        return b.view(values.shape[:-1] if _is_vector(dtype) else values.shape)


def _is_vector(dtype) -> bool:
    """A Warp vector type (Warp's scalar types have _length_ 1 too)."""
    return getattr(dtype, "_length_", 0) > 1


def _rows(a: wp.array, shape: tuple[int, ...]) -> wp.array:
    """The view of `a`'s leading block of `shape` (no memory allocated)."""
    if a.ndim == 1:
        return a[:shape[0]]
    return a[:shape[0], :shape[1]] if a.ndim == 2 else a[tuple(slice(0, k) for k in shape)]


def call_buffers(workspace: Workspace | None, n: int) -> tuple[Workspace, int]:
    """A kernel wrapper's buffers and launch block for n items: the call site's workspace and
    launches of at most its rows (kept between calls: nothing allocated after its first call), or,
    for None, fresh buffers and one launch over all n (at least one row)."""
    return (Workspace(), max(n, 1)) if workspace is None else (workspace, workspace.rows)


class Workspaces:
    """The Workspaces of a per-frame stage, one per kernel call site (`site`, e.g. "object_light.centres"),
    made on first use and kept for the stage's life."""

    def __init__(self) -> None:
        self._sites: dict[str, Workspace] = {}

    def get(self, site: str) -> Workspace:
        if site not in self._sites:
            self._sites[site] = Workspace()
        return self._sites[site]
