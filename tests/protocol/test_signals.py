"""protocol/signals.py in a real child process: SIGINT/SIGTERM stop a main thread that waits on the stop event,
whichever thread of the process the kernel hands the signal to."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

from tests.conftest import ROOT

# A Zenoh session's Rust threads do not block signals, so the kernel may deliver SIGINT to one of them: CPython
# then only notes it, and a main thread asleep in a wait without a timeout never runs the handler. Here the main
# thread blocks the signals itself so that another thread is the only one that can take them.
CHILD = textwrap.dedent("""
    import signal, sys, threading
    from protocol.signals import stop_event_on_signals

    stop = stop_event_on_signals()
    threading.Thread(target=threading.Event().wait, daemon=True).start()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    print("waiting", flush=True)
    print("stopped" if stop.wait(float(sys.argv[1]) if len(sys.argv) > 1 else None) else "timed out", flush=True)
""")


def run_child(sig: int, *argv: str) -> str:
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *argv], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "waiting\n", proc.stderr
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0 and err == "", err
    return out


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_taken_by_another_thread_still_ends_the_wait(sig):
    assert run_child(sig) == "stopped\n"


def test_a_wait_with_a_timeout_still_times_out_and_stops_on_a_signal():
    assert run_child(signal.SIGINT, "600") == "stopped\n"
    proc = subprocess.run([sys.executable, "-c", CHILD, "0.3"], cwd=ROOT, capture_output=True, text=True, timeout=20)
    assert proc.stdout == "waiting\ntimed out\n", proc.stderr


def test_a_signal_arriving_while_the_main_thread_holds_the_events_lock_does_not_deadlock():
    """The handler may interrupt the main thread inside ``Event.wait`` while it holds the event's (not
    re-entrant) lock: a handler that took that lock again would hang the process for good."""
    child = textwrap.dedent("""
        import signal
        from protocol.signals import stop_event_on_signals

        stop = stop_event_on_signals()
        with stop._cond:  # where Event.wait and Event.set hold it
            signal.raise_signal(signal.SIGINT)  # the handler runs here, on this thread
        print("stopped" if stop.wait(5) else "timed out", flush=True)
    """)
    proc = subprocess.run([sys.executable, "-c", child], cwd=ROOT, capture_output=True, text=True, timeout=20)
    assert (proc.stdout, proc.stderr) == ("stopped\n", "")
