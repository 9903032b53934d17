"""Stopping a run on SIGINT (Ctrl-C) or SIGTERM (a cluster scheduler's warning) without raising
inside a callback that XLA or MuJoCo Warp calls.

Python runs a signal handler in the main thread at the next bytecode, wherever that is: inside
MuJoCo Warp's JAX FFI callback, a KeyboardInterrupt aborted the process (`free(): invalid size`)
and nothing was saved. So the handler only records the signal; the run asks
`stop.requested` where Python holds control (between chunks, before the final evaluation),
saves, and returns. A second signal forces the exit at once, without saving.

    with StopSignals() as stop:
        for chunk in ...:
            ...
            if stop.requested:
                break

Outside the main thread (where Python cannot install handlers) it installs nothing and
`requested` stays None: Ctrl-C then raises KeyboardInterrupt as usual.
"""

from __future__ import annotations

import os
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# The pid of the `agents.processes` parent that started this process (`die_with_parent`).
PARENT_PID_ENV = "MJXSUITE_PARENT_PID"
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent() -> None:
    """In a child of `agents.processes` (PARENT_PID_ENV set): a SIGTERM when the parent ends,
    however it ends (SIGKILL included), so that the child stops and saves as on the parent's own
    SIGTERM instead of training on, orphaned. Linux's prctl(PR_SET_PDEATHSIG) where there is one;
    elsewhere a thread that watches the parent's pid. A parent gone before this ran counts too."""
    parent = os.environ.get(PARENT_PID_ENV)
    if not parent:
        return
    try:
        import ctypes

        watched = ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM) != 0
    except (OSError, AttributeError):  # no prctl: not Linux
        watched = True
    if os.getppid() != int(parent):
        os.kill(os.getpid(), signal.SIGTERM)
    elif watched:
        threading.Thread(target=_watch_parent, args=(int(parent),), daemon=True, name="mjxsuite-parent").start()


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        threading.Event().wait(1.0)
    os.kill(os.getpid(), signal.SIGTERM)


def exit_status(signum: int) -> int:
    """The shell's status for a process ended by `signum`: 130 for SIGINT, 143 for SIGTERM."""
    return 128 + int(signum)


# A signal that came before any run installed its handlers (`catch_early`): during the imports
# and the checks of the command line. The run's `StopSignals` takes it over.
_pending: int | None = None


def _early(signum, frame) -> None:
    global _pending
    if _pending is not None:
        os.write(2, f"\n{signal.Signals(signum).name} again: exiting now\n".encode())
        os._exit(exit_status(signum))
    _pending = signum
    os.write(2, f"\n{signal.Signals(signum).name}: stopping before the run starts\n".encode())


def catch_early() -> None:
    """From the first line of the `mjxsuite` command: a signal during its imports (seconds: JAX,
    CUDA's plugin, MuJoCo) is recorded instead of raising there. A KeyboardInterrupt raised
    inside CUDA's plugin start made JAX fall back to the CPU, and one inside an import left a
    traceback. `release_early` or the run's `StopSignals` then act on it."""
    if threading.current_thread() is threading.main_thread():
        for signum in STOP_SIGNALS:
            signal.signal(signum, _early)


def release_early() -> None:
    """Give the signals back their usual meaning (for commands that are no training run); a
    signal that came meanwhile exits now, with its status."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if _pending is not None:
        os._exit(exit_status(_pending))


class _Catching:
    """While active (in the main thread), SIGINT and SIGTERM go to `_handle`; `requested` is the
    first signal's number, one that came during the imports (`catch_early`) included."""

    def __init__(self):
        self.requested: int | None = None
        self._previous: dict[int, object] = {}

    def _handle(self, signum, frame) -> None:
        raise NotImplementedError

    def __enter__(self):
        global _pending
        self.requested, _pending = self.requested or _pending, None  # a signal before the run: act at once
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    @property
    def catching(self) -> bool:
        """Whether the signals come here (in the main thread), not as a KeyboardInterrupt."""
        return bool(self._previous)

    @property
    def name(self) -> str | None:
        """The first signal's name ("SIGINT", "SIGTERM"), None before any."""
        return None if self.requested is None else signal.Signals(self.requested).name


class StopSignals(_Catching):
    """While active, SIGINT and SIGTERM set `requested` (the first signal's number) instead of
    raising; a second one exits the process at once with `exit_status`. Once the run calls
    `finishing`, nothing stops it any more but a second signal, and a first one says so."""

    finishing_what: str | None = None

    def finishing(self, what: str) -> None:
        """From here the run ends `what` (e.g. its final evaluation) whatever a first signal asks,
        and that signal's message says so instead of announcing a stop."""
        self.finishing_what = what

    def _handle(self, signum, frame) -> None:
        name = signal.Signals(signum).name
        if self.requested is not None:
            # Nothing else runs here: the process may be inside an XLA or Warp call.
            os.write(2, f"\n{name} again: exiting now, without saving\n".encode())
            os._exit(exit_status(signum))
        self.requested = signum
        # os.write, not print: print is not reentrant, and the signal may arrive inside a print.
        if self.finishing_what is not None:
            os.write(2, f"\n{name}: the run is past its last checkpoint and finishes {self.finishing_what} "
                        f"(send it again to exit now: the checkpoint holds every chunk, and --resume evaluates "
                        "them)\n".encode())
            return
        os.write(2, f"\n{name}: stopping after the current step of work and saving "
                    "(send it again to exit now, without saving)\n".encode())


class ForwardSignals(_Catching):
    """While active, SIGINT and SIGTERM are passed on to the child processes `children()` returns
    (`subprocess.Popen`s) instead of stopping this one: `agents.processes`'s children are runs
    that stop and save on a first signal and exit at once on a second (`StopSignals`), so each
    signal this process gets reaches each child exactly once. `requested`: the first signal's
    number (one that came before, during the imports, included)."""

    def __init__(self, children):
        super().__init__()
        self.children = children
        self.reached: set[int] = set()  # the pids the first signal was passed on to

    def _handle(self, signum, frame) -> None:
        again = self.requested is not None
        self.requested = self.requested or signum
        os.write(2, f"\n{signal.Signals(signum).name}{' again' if again else ''}: passed on to the training "
                    f"processes ({'they exit now, without saving' if again else 'they stop and save'})\n".encode())
        for child in self.children():
            if child.poll() is None:
                child.send_signal(signum)
                self.reached.add(child.pid)

    def catch_up(self, child) -> None:
        """Pass the first signal on to `child` if it started while the signal came (before
        `children()` listed it), once."""
        if self.requested is not None and child.pid not in self.reached:
            self.reached.add(child.pid)
            child.send_signal(self.requested)
