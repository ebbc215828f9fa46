"""Native libraries' chatter caught at the file-descriptor level.

C and C++ code (Warp's runtime, Open3D's readers and its Filament/Vulkan GUI, libpng, libjpeg)
writes to file descriptors 1 and 2 directly, past Python's sys.stdout/sys.stderr, so Python's
redirection cannot hold it back. The helpers here point the descriptor at a temporary file for
the duration of a block (os.dup2) and hand the text to the caller, who decides what of it the
user sees: as part of photoar's own error line, after a failure, or under -v.
"""
from __future__ import annotations

import contextlib
import ctypes
import io
import logging
import os
import sys
import tempfile
from typing import Iterator


class CapturedText:
    """Text written to a file descriptor inside `captured_fd`; filled in when the block ends."""
    text: str = ""

    def lines(self) -> list[str]:
        return [ln for ln in self.text.splitlines() if ln.strip()]


def _flush_c_stdio() -> None:
    """Flush the C library's stdio buffers (a pipe's stdout is block-buffered in C), so that
    text written inside a block leaves it before the descriptor is restored."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library handle (not on POSIX): nothing buffered to flush
        pass


@contextlib.contextmanager
def captured_fd(fd: int) -> Iterator[CapturedText]:
    """Capture everything written to file descriptor `fd` (1 or 2) inside the block, by native
    code as well as by Python; the text is in the yielded object's `.text` after the block."""
    out = CapturedText()
    stream = sys.stdout if fd == 1 else sys.stderr
    stream.flush()
    _flush_c_stdio()
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield out
        finally:
            stream.flush()
            _flush_c_stdio()
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            out.text = tmp.read().decode("utf-8", "replace")


def captured_stderr() -> contextlib.AbstractContextManager[CapturedText]:
    """`captured_fd(2)`: around a native call whose stderr lines become part of photoar's own
    message (Warp's initialisation, Open3D's mesh reader, OpenCV's image decoders)."""
    return captured_fd(2)


@contextlib.contextmanager
def native_output_held(show: bool = False, on_failure: bool = True) -> Iterator[None]:
    """Run a block with native code's stdout and stderr held back while Python's own output
    (print, the "photoar" log) still reaches the terminal: descriptors 1 and 2 are captured, and
    sys.stdout / sys.stderr and the log handlers that wrote to them write to copies of the
    original descriptors meanwhile. The held text is written to stderr after the block when it
    raised (unless `on_failure` is False: the caller handles the failure itself) or with `show`
    (the -v flag); otherwise it is dropped."""
    sys.stdout.flush()
    sys.stderr.flush()
    old_out, old_err = sys.stdout, sys.stderr
    new_out = io.TextIOWrapper(os.fdopen(os.dup(1), "wb"), encoding=old_out.encoding or "utf-8",
                               errors="replace", line_buffering=True)
    new_err = io.TextIOWrapper(os.fdopen(os.dup(2), "wb"), encoding=old_err.encoding or "utf-8",
                               errors="backslashreplace", line_buffering=True)
    handlers = [h for lg in (logging.getLogger(), logging.getLogger("photoar")) for h in lg.handlers
                if isinstance(h, logging.StreamHandler) and h.stream in (old_out, old_err)]
    streams = [h.stream for h in handlers]
    failed = False
    out = err = None
    try:
        with captured_fd(1) as out, captured_fd(2) as err:
            sys.stdout, sys.stderr = new_out, new_err
            for h in handlers:
                h.setStream(new_out if h.stream is old_out else new_err)
            try:
                yield
            except BaseException:
                failed = True
                raise
            finally:
                sys.stdout, sys.stderr = old_out, old_err
                for h, s in zip(handlers, streams):
                    h.setStream(s)
                new_out.flush()
                new_err.flush()
    finally:
        new_out.close()
        new_err.close()
        if (failed and on_failure) or show:
            held = "".join(t.text for t in (out, err) if t is not None and t.text)
            if held:
                sys.stderr.write(held if held.endswith("\n") else held + "\n")
                sys.stderr.flush()
