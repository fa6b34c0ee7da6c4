"""vpr.interrupts: a signal during a deferred section is raised when the section ends."""
import os
import signal

import pytest

from vpr.interrupts import Terminated, deferred, import_held, on_sigterm, restore, stopped_import


@pytest.fixture
def sigterm_raises():

    saved = on_sigterm()
    yield
    restore(saved)


@pytest.mark.slow
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


def test_a_stop_a_loader_swallows_is_raised_once_the_module_is_loaded(tmp_path, monkeypatch):
    # a loader with a bare except (as OpenCV's): the stop that came while it ran is lost without the hold
    (tmp_path / "swallows_a_stop.py").write_text(
        "import signal\ntry:\n    signal.raise_signal(signal.SIGINT)\n    for _ in range(1000): pass\n"
        "except:\n    pass\nLOADED = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import sys

    with pytest.raises(KeyboardInterrupt):
        import_held("swallows_a_stop")
    assert sys.modules.pop("swallows_a_stop").LOADED


def test_an_import_error_raised_by_a_stop_is_told_apart():
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise ImportError("initialization failed") from e
    except ImportError as e:
        assert stopped_import(e)
    assert not stopped_import(ImportError("No module named 'onnxruntime'"))
    assert not stopped_import(KeyboardInterrupt())


def test_a_finalizer_failing_after_a_stop_is_not_reported(monkeypatch):
    import sys
    import time

    class HalfBuilt:  # a library's wrapper whose constructor the stop cut short: its __del__ fails
        def __del__(self):
            raise AttributeError("'HalfBuilt' object has no attribute '_ptr'")

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_type))
    saved = on_sigterm()
    try:
        HalfBuilt()  # before any stop: reported, as ever
        assert seen == [AttributeError]
        with pytest.raises(Terminated):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(2)
        HalfBuilt()
        assert seen == [AttributeError]
    finally:
        restore(saved)
    HalfBuilt()  # the run's hooks put back: reported again
    assert seen == [AttributeError, AttributeError]


def test_ctrl_c_is_noted_as_a_stop_and_put_back():
    before = signal.getsignal(signal.SIGINT)
    saved = on_sigterm()
    try:
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
            import time

            time.sleep(2)
    finally:
        restore(saved)
    assert signal.getsignal(signal.SIGINT) is before
