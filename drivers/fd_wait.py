"""Instrument links that work whatever their descriptor numbers: `select()` over `poll()`.

`select.select()` takes descriptors below FD_SETSIZE (1024) only: a process holding more
(an operator screen with a thousand idle browser connections) gets "filedescriptor out of
range in select()" from the first link opened after that, and the link looks dropped. The
station's own code waits with `poll` (socket timeouts, `selectors`), but the transport
libraries it drives instruments with wait with `select.select()`: pyserial (the fixture's
ports, ASRL instruments, `socket://`), pyvisa-py (raw SCPI sockets, VXI-11, Prologix) and
pymodbus's TCP client. `use_poll()` gives each of those modules a `select` whose `select()`
is this module's `select_by_poll` (same arguments, same answers, any descriptor number); the
rest of the `select` module is the real one. tests/drivers/test_fd_wait.py drives every
transport with its descriptor above 1024, so a library update that adds a `select()` of its
own is caught there.
"""

from __future__ import annotations

import errno
import importlib
import math
import os
import select as _select
import types
from collections.abc import Iterable, Sequence
from typing import Any

# the library modules that call select.select() on an instrument link's descriptor
LIBRARY_MODULES = (
    "serial.serialposix",
    "serial.urlhandler.protocol_socket",
    "pyvisa_py.tcpip",
    "pyvisa_py.prologix",
    "pyvisa_py.protocols.rpc",
    "pymodbus.client.tcp",
)
_READ = _select.POLLIN | _select.POLLHUP | _select.POLLERR
_WRITE = _select.POLLOUT | _select.POLLHUP | _select.POLLERR


def _fd(obj: Any) -> int:
    fd = obj if isinstance(obj, int) else obj.fileno()
    if not isinstance(fd, int) or fd < 0:
        raise ValueError(f"file descriptor cannot be a negative integer ({fd})")
    return fd


def select_by_poll(
    rlist: Sequence[Any], wlist: Sequence[Any], xlist: Sequence[Any],
    timeout: float | None = None,
) -> tuple[list[Any], list[Any], list[Any]]:
    """`select.select()`'s contract over `poll()`: the objects (or descriptors) of each list
    that are ready; a hang-up or error counts as ready to read and to write, as select says;
    a closed descriptor is OSError(EBADF) as select raises it."""
    if timeout is not None and timeout < 0:
        raise ValueError("timeout must be non-negative")
    # poll waits whole milliseconds: round up so a short wait is never a busy loop
    wait_ms = None if timeout is None else math.ceil(timeout * 1000)
    if not wlist and not xlist:  # the fast path: pyserial's read, pymodbus's recv
        return _readable(rlist, wait_ms), [], []
    poller = _select.poll()
    masks: dict[int, int] = {}
    for objs, mask in ((rlist, _READ), (wlist, _WRITE), (xlist, _select.POLLPRI)):
        for obj in objs:
            fd = _fd(obj)
            masks[fd] = masks.get(fd, 0) | mask
    for fd, mask in masks.items():
        poller.register(fd, mask)
    events = dict(poller.poll(wait_ms))
    _raise_if_closed(events.values())
    return (
        _ready(rlist, events, _READ),
        _ready(wlist, events, _WRITE),
        _ready(xlist, events, _select.POLLPRI),
    )


def _readable(rlist: Sequence[Any], wait_ms: int | None) -> list[Any]:
    poller = _select.poll()
    for obj in rlist:
        poller.register(_fd(obj), _READ)
    events = poller.poll(wait_ms)
    if not events:
        return []
    _raise_if_closed(ev for _, ev in events)
    ready = {fd for fd, ev in events if ev & _READ}
    return [obj for obj in rlist if _fd(obj) in ready]


def _raise_if_closed(events: Iterable[int]) -> None:
    """select raises EBADF for a closed descriptor; poll reports it as POLLNVAL."""
    if any(ev & _select.POLLNVAL for ev in events):
        raise OSError(errno.EBADF, os.strerror(errno.EBADF))


def _ready(objs: Iterable[Any], events: dict[int, int], mask: int) -> list[Any]:
    return [obj for obj in objs if events.get(_fd(obj), 0) & mask]


class _PollSelectModule(types.ModuleType):
    """The `select` module with `select()` done by poll; every other name is the real one."""

    select = staticmethod(select_by_poll)

    def __getattr__(self, name: str) -> Any:
        return getattr(_select, name)


_POLL_SELECT = _PollSelectModule("select")


def use_poll(module_names: Iterable[str] = LIBRARY_MODULES) -> list[str]:
    """Give each importable library module the poll-based `select`; the names done (a
    library not installed is skipped: its transport is not used then)."""
    done = []
    for name in module_names:
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        if getattr(module, "select", None) in (_select, _POLL_SELECT):
            module.select = _POLL_SELECT  # type: ignore[attr-defined]
            done.append(name)
    return done
