"""vpr.interrupts: a signal during a deferred section is raised when the section ends."""
import os
import signal

import pytest

from vpr.interrupts import Terminated, deferred, on_sigterm


@pytest.fixture
def sigterm_raises():
    import sys

    handler, hook = on_sigterm()
    yield
    signal.signal(signal.SIGTERM, handler)
    sys.unraisablehook = hook


def test_a_stop_inside_a_finalizer_is_sent_again(sigterm_raises, capsys):
    import time

    class Stops:
        def __del__(self):  # Python drops an exception raised here (a signal that lands in a finalizer)
            raise Terminated()

    with pytest.raises(Terminated):
        Stops()
        time.sleep(2)  # the stop comes again where it can be raised
    assert "Traceback" not in capsys.readouterr().err


def test_signal_in_a_deferred_section_is_raised_after_it(sigterm_raises):
    done = []
    with pytest.raises(Terminated):
        with deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            done.append("rest of the section")
    assert done == ["rest of the section"]
    with pytest.raises(KeyboardInterrupt):
        with deferred():
            os.kill(os.getpid(), signal.SIGINT)
            done.append("again")
    assert done[-1] == "again"


def test_second_signal_is_handled_at_once_and_handlers_come_back(sigterm_raises):
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    done = []
    with pytest.raises(Terminated):
        with deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
            done.append("not reached")
    assert done == []
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_an_error_in_the_section_wins_over_a_held_signal(sigterm_raises):
    with pytest.raises(ValueError):
        with deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            raise ValueError("bad input")


def test_no_signal_no_change(sigterm_raises):
    with deferred():
        x = 1
    assert x == 1
