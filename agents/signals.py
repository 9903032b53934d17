"""Stopping a run on SIGINT (Ctrl-C) or SIGTERM (a scheduler's warning) without raising inside a
callback that XLA or MuJoCo Warp calls (docs/mjx.md, "MuJoCo Warp and CUDA graphs"): the handler only
records the signal, and the run checks `stop.requested` between chunks, saves and returns. A second
signal exits at once, without saving. Outside the main thread nothing is installed: Ctrl-C raises
KeyboardInterrupt as usual.
"""

from __future__ import annotations

import faulthandler
import os
import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
STACKS_SIGNAL = signal.SIGUSR1  # `kill -USR1 PID`: every thread's stack to stderr (`dump_stacks_on_signal`)
# The pid of the `agents.processes` parent of this process (`die_with_parent`).
PARENT_PID_ENV = "MJXSUITE_PARENT_PID"
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent() -> None:
    """In a child of `agents.processes`: a SIGTERM when the parent ends, even by SIGKILL, so that the child
    stops and saves instead of training on, orphaned (prctl, or a thread watching the parent's pid)."""
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


def dump_stacks_on_signal() -> None:
    """On STACKS_SIGNAL, every thread's stack to stderr (fd 2), by faulthandler's C handler: it answers where a
    run stuck inside an XLA or Warp call never reaches `StopSignals`' Python handlers (docs/reliability.md)."""
    if threading.current_thread() is threading.main_thread():
        faulthandler.register(STACKS_SIGNAL, file=2, all_threads=True, chain=False)


def exit_status(signum: int) -> int:
    """The shell's status for a process ended by `signum`: 130 for SIGINT, 143 for SIGTERM."""
    return 128 + int(signum)


# A signal that came before any run installed its handlers (`catch_early`); `StopSignals` takes it over.
_pending: int | None = None


def _early(signum, frame) -> None:
    global _pending
    if _pending is not None:
        os.write(2, f"\n{signal.Signals(signum).name} again: exiting now\n".encode())
        os._exit(exit_status(signum))
    _pending = signum
    os.write(2, f"\n{signal.Signals(signum).name}: stopping before the run starts\n".encode())


def catch_early() -> None:
    """Record a signal during the command's imports instead of raising there (inside CUDA's plugin start,
    a KeyboardInterrupt made JAX fall back to the CPU); `release_early` or `StopSignals` act on it."""
    if threading.current_thread() is threading.main_thread():
        for signum in STOP_SIGNALS:
            signal.signal(signum, _early)


def release_early() -> None:
    """Give the signals back their usual meaning (commands that train nothing); one that came exits now."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if _pending is not None:
        os._exit(exit_status(_pending))


class _Catching:
    """While active, SIGINT and SIGTERM go to `_handle`; `requested`: the first one's number."""

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
    """While active, SIGINT and SIGTERM set `requested` instead of raising; a second one exits at
    once. After `finishing`, only a second signal stops the run."""

    finishing_what: str | None = None

    def finishing(self, what: str) -> None:
        """From here the run ends `what` whatever a first signal asks, and that signal's message says so."""
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
    """While active, SIGINT and SIGTERM are passed on to the `subprocess.Popen`s `children()` returns,
    each signal to each child exactly once (a child's second signal exits it without saving)."""

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
        """Pass the first signal on, once, to `child` if it started as the signal came."""
        if self.requested is not None and child.pid not in self.reached:
            self.reached.add(child.pid)
            child.send_signal(self.requested)
