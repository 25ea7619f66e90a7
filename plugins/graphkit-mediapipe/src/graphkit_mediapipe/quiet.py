"""Keep mediapipe's own log lines off the user's terminal.

mediapipe's C++ side (absl/glog, TFLite) writes lines such as ``INFO: Created TensorFlow Lite
XNNPACK delegate for CPU.`` and ``W0000 00:00:… inference_feedback_manager.cc:114] …`` straight
to file descriptor 2, and protobuf warns ``SymbolDatabase.GetPrototype() is deprecated`` from
Python.  :func:`mediapipe` imports the module with those silenced; :func:`native_logs_filtered`
runs a block with fd 2 read through a pipe that drops the lines in those formats and passes every
other line (graphkit's own messages, other threads' output) through unchanged.
``GRAPHKIT_NATIVE_LOG=FILE`` appends the dropped lines to FILE instead.
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import threading
import warnings

#: absl/glog lines (``W0000 00:00:1700000000.1 123 file.cc:114] …``), TFLite's ``INFO: …`` and
#: absl's pre-initialisation notice
THIRD_PARTY_LINE = re.compile(
    rb"^(?:[IWEF]\d{4} [\d:.]+\s+\d+ \S+:\d+\] "
    rb"|INFO: (?:Created TensorFlow Lite|Initialized TensorFlow Lite|TfLite)"
    rb"|WARNING: All log messages before absl::InitializeLog\(\) is called are written to STDERR)")

warnings.filterwarnings("ignore", message=r"SymbolDatabase\.GetPrototype\(\) is deprecated",
                        category=UserWarning)

_lock = threading.Lock()
_depth = 0
_saved: int | None = None
_reader: threading.Thread | None = None


def _pump(read_fd: int, out_fd: int) -> None:
    sink = os.environ.get("GRAPHKIT_NATIVE_LOG")
    buf = b""
    with os.fdopen(read_fd, "rb", buffering=0) as r:
        while True:
            chunk = r.read(65536)
            if not chunk:
                break
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for line in lines:
                _route(line + b"\n", out_fd, sink)
    if buf:
        _route(buf, out_fd, sink)


def _route(line: bytes, out_fd: int, sink: str | None) -> None:
    if THIRD_PARTY_LINE.match(line):
        if sink:
            with contextlib.suppress(OSError), open(sink, "ab") as f:
                f.write(line)
        return
    with contextlib.suppress(OSError):
        os.write(out_fd, line)


@contextlib.contextmanager
def native_logs_filtered():
    """Run a block with mediapipe/absl/TFLite log lines on fd 2 dropped (nests; thread-safe)."""
    global _depth, _saved, _reader
    with _lock:
        if _depth == 0:
            try:
                sys.stderr.flush()
                saved = os.dup(2)
                r, w = os.pipe()
                os.dup2(w, 2)
                os.close(w)
            except OSError:  # no usable fd 2: nothing to filter
                saved = None
            if saved is not None:
                _saved = saved
                _reader = threading.Thread(target=_pump, args=(r, saved), daemon=True,
                                           name="graphkit-mediapipe-logs")
                _reader.start()
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _saved is not None:
                with contextlib.suppress(Exception):
                    sys.stderr.flush()
                os.dup2(_saved, 2)  # closes the pipe's last write end: the reader sees EOF
                _reader.join(timeout=5)
                os.close(_saved)
                _saved, _reader = None, None


def mediapipe():
    """``import mediapipe`` with its log lines kept off the terminal."""
    with native_logs_filtered():
        import mediapipe as mp

        with contextlib.suppress(Exception):  # absl's Python logging: errors only
            from absl import logging as absl_logging

            absl_logging.set_verbosity(absl_logging.ERROR)
    return mp
