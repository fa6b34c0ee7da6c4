"""Ctrl-C and SIGTERM: how a run stops, and the few sections it must not stop inside."""
from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
import threading

__all__ = ["Terminated", "on_sigterm", "restore", "deferred", "import_held", "stopped_import"]


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled as Ctrl-C: what is being written is dropped (atomic writes), one line, status 143."""


class _Stop:
    """Whether a stop was raised by the handlers of :func:`on_sigterm` since they were installed."""

    raised = False


def _raise_terminated(signum, frame):
    _Stop.raised = True
    raise Terminated()


def _raise_interrupt(signum, frame):
    _Stop.raised = True
    raise KeyboardInterrupt()


def _stop_again(hook):
    """``sys.unraisablehook`` that sends again a stop raised inside a finalizer or weakref callback (where Python
    drops it with a traceback): a run stopped there must still stop, with one line. Once a stop was raised, the
    errors of finalizers are dropped: an object the stop cut short while it was built (a library's half-made
    wrapper) fails in its ``__del__``, a traceback after the run's one line."""
    def handle(u):
        if not isinstance(u.exc_value, KeyboardInterrupt):
            return None if _Stop.raised else hook(u)
        again = signal.SIGTERM if isinstance(u.exc_value, Terminated) else signal.SIGINT
        timer = threading.Timer(0.01, signal.raise_signal, (again,))
        timer.daemon = True  # never keeps a finished process alive to signal it
        timer.start()
    return handle


def on_sigterm():
    """Handle SIGTERM as an interrupt, and Ctrl-C as Python does (where its handler is Python's), both noted as a stop
    (main thread only); returns what they replaced, for :func:`restore`, or None."""
    try:
        term = signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:  # not the main thread (e.g. main() called from a worker thread)
        return None
    interrupt = signal.getsignal(signal.SIGINT)
    if interrupt is signal.default_int_handler:
        signal.signal(signal.SIGINT, _raise_interrupt)
    saved = term, interrupt, sys.unraisablehook
    sys.unraisablehook = _stop_again(sys.unraisablehook)
    _Stop.raised = False
    return saved


def restore(saved) -> None:
    """Put back what :func:`on_sigterm` replaced (``saved``: its result; None: nothing)."""
    if saved is None:
        return
    term, interrupt, hook = saved
    signal.signal(signal.SIGTERM, term)
    if signal.getsignal(signal.SIGINT) is _raise_interrupt:
        signal.signal(signal.SIGINT, interrupt)
    sys.unraisablehook = hook
    _Stop.raised = False


def _deliver(signum: int, handler) -> None:
    if callable(handler):
        handler(signum, None)
    elif handler == signal.SIG_DFL:
        os.kill(os.getpid(), signum)  # the default action (end the process), now that it is safe


@contextlib.contextmanager
def deferred(signums=(signal.SIGINT, signal.SIGTERM)):
    """Hold ``signums`` while the block runs; the first one that came is raised when it ends.

    A second signal of the same kind during the block is handled at once (the usual "press Ctrl-C twice" for a section
    that hangs). Outside the main thread, where Python delivers no signals, the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    saved = {}

    def hold(signum, frame):
        if signum in got:
            _deliver(signum, saved[signum])
        got.append(signum)

    try:
        for s in signums:
            saved[s] = signal.signal(s, hold)
        yield
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
    if got:
        _deliver(got[0], saved[got[0]])


def import_held(name: str):
    """Import module ``name`` (and what it imports) with Ctrl-C and SIGTERM held until it is loaded; returns it.

    Some libraries' loaders lose a stop that comes while they load: a bare ``except:`` (OpenCV's) swallows it,
    and an extension module's initialisation turns it into ``ImportError: initialization failed`` (pybind11,
    NumPy's C API). Held, the stop is raised once the import is done.
    """
    with deferred():
        return importlib.import_module(name)


def stopped_import(exc: BaseException) -> bool:
    """Whether ``exc`` is an ``ImportError`` that a stop (Ctrl-C, SIGTERM) raised while a module loaded."""
    seen = set()
    e = exc if isinstance(exc, ImportError) else None
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False
