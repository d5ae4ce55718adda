"""Cyclone DDS's own log lines (warnings, errors) through zensim's logging, at a bounded rate.

Cyclone DDS prints a warning for every malformed RTPS packet it receives ("malformed packet received
from vendor ..."), straight to stderr: 20k garbage packets at the adapter's ports made 11 836 lines
(3.2 MB). Its `Tracing/Verbosity` setting does not help: it governs the trace, not these warnings.
So the process's log sink (`dds_set_log_sink`, a C callback for fatal/error/warning/info lines) is
replaced by one that hands each line to a RateLimitedLog per source line of Cyclone's code: at most
one line a second from each place, with a count of the ones held back. Those places are finite (the
library's code), so the limiters are too.

The callback runs on Cyclone's threads (its receive thread, for packets): it is kept short.
"""

from __future__ import annotations

import atexit
import ctypes
import logging
import threading

from cyclonedds.internal import DDS

from zensim.common.logs import RateLimitedLog

logger = logging.getLogger("zensim.cyclonedds")

LOG_PERIOD_S = 1.0
"""Shortest time between two lines from the same place in Cyclone's code, s."""

DDS_LC_FATAL = 1
DDS_LC_ERROR = 2
DDS_LC_WARNING = 4


class LogData(ctypes.Structure):
    """dds_log_data_t (dds/ddsrt/log.h)."""

    _fields_ = [
        ("priority", ctypes.c_uint32),
        ("domid", ctypes.c_uint32),
        ("file", ctypes.c_char_p),
        ("line", ctypes.c_uint32),
        ("function", ctypes.c_char_p),
        ("message", ctypes.c_char_p),
        ("size", ctypes.c_size_t),
        ("hdrsize", ctypes.c_size_t),
    ]


LOG_WRITE_FN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.POINTER(LogData))

_limiters: dict[tuple[bytes, int], RateLimitedLog] = {}
_limiters_lock = threading.Lock()
_installed: list[object] = []  # the C callback object, kept alive while Cyclone may call it


def _level(priority: int) -> int:
    if priority & (DDS_LC_FATAL | DDS_LC_ERROR):
        return logging.ERROR
    if priority & DDS_LC_WARNING:
        return logging.WARNING
    return logging.INFO


def _sink(_userdata: int | None, data_p: ctypes._Pointer[LogData]) -> None:
    try:
        data = data_p.contents
        site = (data.file or b"", int(data.line))
        with _limiters_lock:
            limiter = _limiters.get(site)
            if limiter is None:
                limiter = _limiters[site] = RateLimitedLog(logger, LOG_PERIOD_S)
        text = ctypes.string_at(data.message, data.size)  # the line without Cyclone's header
        limiter.log(_level(data.priority), "%s", text.decode(errors="replace").rstrip())
    except Exception:  # noqa: BLE001 - an exception must never unwind into Cyclone's C thread
        pass


def route_cyclone_log() -> None:
    """Send Cyclone DDS's log lines of this process through rate-limited zensim logging (idempotent)."""
    if _installed:
        return
    ddsc = DDS._dll_handle  # the library the binding itself calls
    callback = LOG_WRITE_FN(_sink)
    ddsc.dds_set_log_sink.argtypes = [ctypes.c_void_p, ctypes.c_void_p]  # a callback, or NULL: Cyclone's own
    ddsc.dds_set_log_sink.restype = None
    ddsc.dds_set_log_sink(ctypes.cast(callback, ctypes.c_void_p), None)
    _installed.append(callback)

    def restore() -> None:
        # Before the interpreter goes away: Cyclone's threads may still log while the process ends.
        # dds_set_log_sink returns only once no thread uses the old sink.
        ddsc.dds_set_log_sink(None, None)

    atexit.register(restore)
