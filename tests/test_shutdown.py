"""SIGTERM stops a service whatever its main thread is doing (services/common/shutdown.py).

Each test runs a small program on the product's stop_on_signals() in a process of its own, the way every
service and `zensim up` use it, and signals it from outside.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

POLLING_SERVICE = """
import threading
from zensim.common.logs import setup_logging
from zensim.common.shutdown import stop_on_signals

setup_logging("INFO")
stop = stop_on_signals()

def busy():  # other threads that want the GIL, as zenoh's callbacks do: they stretch the main thread's polls
    while True:
        sum(range(1000))

for _ in range(2):
    threading.Thread(target=busy, daemon=True).start()
print("ready", flush=True)
while not stop.wait(%(poll_s)s):
    pass
print("stopped", flush=True)
"""

STUBBORN_SERVICE = """
import time
from zensim.common.logs import setup_logging
from zensim.common.shutdown import stop_on_signals

setup_logging("INFO")
stop = stop_on_signals()
print("ready", flush=True)
while True:  # a service that does not look at its stop event: only a second signal ends it
    time.sleep(0.01)
"""


def _start(program: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline() == "ready\n", proc.communicate(timeout=10)
    return proc


def test_sigterm_stops_a_main_thread_that_polls_its_stop_event_every_time():
    # A main thread that polls stop.wait() holds the event's lock part of each poll. The Python signal handler
    # that set the event ran on that thread and could wait for that lock for ever: it hung about one try in two
    # here with a zero poll, and 3 CI runs out of ~30 with the router's 0.5 s poll.
    procs = [_start(POLLING_SERVICE % {"poll_s": poll_s}) for poll_s in (0, 0, 0, 0, 0, 0.0005, 0.0005, 0.5)]
    time.sleep(0.2)  # into the middle of their polling
    for proc in procs:
        proc.send_signal(signal.SIGTERM)
    outcomes = []
    for proc in procs:
        try:
            out, err = proc.communicate(timeout=10)
            outcomes.append((proc.returncode, out.strip(), "SIGTERM received: stopping" in err))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            outcomes.append(("hung", "", False))
    assert outcomes == [(0, "stopped", True)] * len(procs)


def test_sigint_stops_it_too_and_a_second_signal_exits_at_once_with_1():
    proc = _start(STUBBORN_SERVICE)
    try:
        proc.send_signal(signal.SIGINT)
        time.sleep(0.5)
        assert proc.poll() is None, "one signal only asks the loops to stop"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=5)
        assert proc.returncode == 1, err
        assert "SIGINT received: stopping" in err and "second SIGTERM: exiting now" in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_the_stop_event_is_set_within_a_moment_of_the_signal():
    program = POLLING_SERVICE.replace('print("stopped", flush=True)', 'print("stopped", time.monotonic(), flush=True)')
    proc = _start("import time\n" + program % {"poll_s": "None"})
    try:
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
        word, at = out.split()
        assert word == "stopped" and float(at) - sent < 0.5 and proc.returncode == 0, (out, proc.returncode)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
