"""One exit path for every way a station process ends short of kill -9 (docs/safety.md).

`station run`, `station demo` and `station ui` do their work inside an `ExitPath` and
`attach` what stops their run. Then:

* SIGTERM (a service manager, `kill`, `docker stop`), SIGINT (Ctrl-C), SIGHUP (the terminal
  or the ssh session closed) and SIGQUIT: the run in progress is asked to stop, ABORTED with
  the signal named. The run's own end does everything else - the safe state commanded and
  read back, the record, certificate and manifest, the results database, the `.running` lock
  released - and the command exits 2.
* A further signal while that goes on is said, not obeyed: the safe-state pass and the
  sealing finish (a second Ctrl-C, a service manager's second SIGTERM).
* That end is bounded: a process still there `bound_s` wall seconds after the first signal
  exits 2 at once; its run folder, left RUNNING with its lock, is then recovered as a crashed
  run at the next start.
* An uncaught exception in any thread (threading.excepthook) ends the run in progress as
  ERROR, naming the thread and the exception; the traceback goes to the log.
* Before anything is attached (the simulated bench still starting) a signal unwinds as Ctrl-C
  does (KeyboardInterrupt, exit 2): no instrument has been commanded yet.

The signal handler only queues the signal: the work (saying so, aborting the run) is done on
the exit path's own thread, so a signal that arrives while the main thread holds a lock or is
halfway through a print can neither deadlock nor garble it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any, TextIO

from procedures.engine.safe_state import SafeStatePolicy

log = logging.getLogger(__name__)

SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGQUIT)
# `nohup station run ...` starts the station with SIGHUP ignored: it asked that a closed
# terminal not stop the run, so an inherited ignore of SIGHUP is kept. (SIGINT and SIGQUIT
# are obeyed even when inherited ignored: a shell script's background job gets them ignored
# without anybody asking, and kill -INT must still stop the run safely.)
KEEP_IGNORED = (signal.SIGHUP,)


def _obeyed() -> list[signal.Signals]:
    """The signals the exit path handles: all of SIGNALS but those of KEEP_IGNORED that the
    process inherited as ignored."""
    return [s for s in SIGNALS
            if not (s in KEEP_IGNORED and signal.getsignal(s) is signal.SIG_IGN)]


# why the run stopped, as its record says it (the engine adds "in step ...")
REASONS: dict[signal.Signals, str] = {
    signal.SIGTERM: "station asked to stop (SIGTERM)",
    signal.SIGINT: "the operator pressed Ctrl-C (SIGINT)",
    signal.SIGHUP: "the station's terminal or session closed (SIGHUP)",
    signal.SIGQUIT: "station asked to quit (SIGQUIT)",
}
# wall seconds for the record, certificate, manifest and results database after the pass
SEAL_ALLOWANCE_S = 60.0
EXIT_CODE = 2  # the CLI contract: 0 PASS, 1 FAIL, 2 error or abort

# stop(reason, error): end the run in progress, ERROR when `error`, else ABORTED
Stop = Callable[[str, bool], None]


def exit_bound_s(policy: SafeStatePolicy) -> float:
    """Wall seconds a stop may take at most: the safe-state pass's longest retries (as on a
    real bench, where station seconds are wall seconds), its last reply timeout, the sealing."""
    return (
        max(policy.deadline_s, policy.wall_floor_s)
        + 2 * policy.max_timeout_wall_s
        + SEAL_ALLOWANCE_S
    )


class _Tolerant:
    """A standard stream whose writes may fail (the terminal is gone after SIGHUP): a failed
    write is dropped, never raised into the run's own end."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except (OSError, ValueError):
            return len(text)

    def flush(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self._stream.flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


class ExitPath:
    """Signals and uncaught thread exceptions of one station command; see the module doc."""

    def __init__(
        self,
        command: str,
        *,
        bound_s: float = exit_bound_s(SafeStatePolicy()),
        exit_now: Callable[[int], None] = os._exit,
    ) -> None:
        self.command = command
        self.bound_s = bound_s
        self._exit_now = exit_now  # tests give their own; the product's is os._exit
        self._stop: Stop | None = None
        self._events: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._worker: threading.Thread | None = None
        self._previous: dict[int, Any] = {}
        self._previous_hook: Callable[[threading.ExceptHookArgs], Any] | None = None
        self._deadline: threading.Timer | None = None
        self.signals: list[int] = []  # as they came (read on the exit path's thread)
        self.stopped = threading.Event()  # set once the attached stop has been asked
        self.reason = ""  # of the first stop: a signal or an uncaught exception
        self.error = False  # that stop was an exception (ERROR), not a signal (ABORTED)

    # ------------------------------------------------------------ the command's side

    def __enter__(self) -> ExitPath:
        self._worker = threading.Thread(target=self._work, name="exit-path", daemon=True)
        self._worker.start()
        if threading.current_thread() is threading.main_thread():
            self._previous = {sig: signal.signal(sig, self._on_signal) for sig in _obeyed()}
        self._previous_hook = threading.excepthook
        threading.excepthook = self._on_thread_exception
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        if self._previous_hook is not None:
            threading.excepthook = self._previous_hook
        self._events.put(("close", None))
        if self._worker is not None:
            self._worker.join(5.0)
        if self._deadline is not None:
            self._deadline.cancel()

    def attach(self, stop: Stop) -> None:
        """From now on a signal or an uncaught thread exception calls `stop(reason, error)`
        (once: the first one's reason stands); before, a signal unwinds (KeyboardInterrupt)."""
        self._stop = stop

    @property
    def signalled(self) -> bool:
        return bool(self.signals)

    # ------------------------------------------------------------ handlers (any thread)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        # in the main thread, between two of its bytecodes: queue only (SimpleQueue.put is
        # reentrant), never print or lock here
        self._events.put(("signal", signum))
        if self._stop is None:
            raise KeyboardInterrupt

    def _on_thread_exception(self, args: threading.ExceptHookArgs) -> None:
        if args.exc_type is SystemExit:
            return
        name = args.thread.name if args.thread is not None else "?"
        log.error(
            "uncaught exception in thread %s", name,
            exc_info=(args.exc_type, args.exc_value, args.exc_traceback),  # type: ignore[arg-type]
        )
        what = f"{args.exc_type.__name__}: {args.exc_value}"
        self._events.put(("exception", f"internal error in thread {name!r} ({what}); "
                                       "report this with the run folder"))

    # ------------------------------------------------------------ the exit path's thread

    def _work(self) -> None:
        while True:
            kind, value = self._events.get()
            if kind == "close":
                return
            try:
                if kind == "signal":
                    self._signal(int(value))
                else:
                    self._exception(str(value))
            except Exception:  # the exit path must outlive any one failure of its own
                log.exception("the exit path failed handling %s", kind)

    def _say(self, text: str) -> None:
        with contextlib.suppress(OSError, ValueError):
            print(f"station {self.command}: {text}", file=sys.stderr, flush=True)

    def _signal(self, signum: int) -> None:
        self.signals.append(signum)
        sig = signal.Signals(signum)
        name = sig.name
        if signum == signal.SIGHUP:  # the terminal may be gone: output must not fail the run
            sys.stdout = _Tolerant(sys.stdout)
            sys.stderr = _Tolerant(sys.stderr)
        if self._stop is None:
            return  # before the run: the handler raised KeyboardInterrupt in the main thread
        if len(self.signals) > 1:
            self._say(
                f"{name} again: the bench is still being made safe and the record sealed; "
                f"the station exits when that is done (within {self.bound_s:.0f} s)"
            )
            return
        self._say(f"{name}: abort requested: making the bench safe...")
        self._arm_deadline()
        self._ask_stop(REASONS.get(sig, f"station stopped by {name}"), error=False)

    def _exception(self, reason: str) -> None:
        self._say(f"{reason}: ending the run")
        if self._stop is not None:
            self._ask_stop(reason, error=True)

    def _ask_stop(self, reason: str, *, error: bool) -> None:
        if not self.stopped.is_set():
            self.reason, self.error = reason, error
        self.stopped.set()
        assert self._stop is not None
        self._stop(reason, error)

    def _arm_deadline(self) -> None:
        self._deadline = threading.Timer(self.bound_s, self._give_up)
        self._deadline.name = "exit-path-deadline"
        self._deadline.daemon = True
        self._deadline.start()

    def _give_up(self) -> None:
        self._say(
            f"the run did not end within {self.bound_s:.0f} s of the signal; exiting now: its "
            "folder is marked ERROR at the next start; check that the bench is safe"
        )
        self._exit_now(EXIT_CODE)
