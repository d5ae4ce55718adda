"""The CI log's check (scripts/check-test-log, run by .ci/run): no DDS participant of the test process spins
at its exit (issue 26: 16 773 lines of Cyclone's "recvUC ... retcode -52" after pytest's summary).

The check itself is tried on a log with such lines and on a clean one; then a real test run that opens
an SDK client and a writer of its own in the test process (the sport-request flood test) is checked the way CI checks its log.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
CHECK = REPO / "scripts" / "check-test-log"
SPIN = "1795784282.782416 [0] recvUC: UDP recvmsg sock 139: ret 0 retcode -52\n"


def check(log: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(CHECK), str(log)], capture_output=True, text=True, timeout=30)


def test_the_check_fails_a_log_with_a_spinning_participant_and_passes_a_clean_one(tmp_path: Path) -> None:
    summary = "........\n8 passed in 12.00s\n"
    clean, spun = tmp_path / "clean.log", tmp_path / "spun.log"
    clean.write_text(summary)
    spun.write_text(summary + SPIN * 3)
    assert check(clean).returncode == 0
    result = check(spun)
    assert result.returncode == 1 and "3 lines" in result.stderr and "recvUC" in result.stderr, result


@pytest.mark.skipif(not os.environ.get("ZENSIM_UNITREE_SDK2_PYTHON"), reason="needs the SDK tests' setup")
def test_a_test_run_with_sdk_clients_in_its_process_exits_without_a_spin(tmp_path: Path) -> None:
    log = tmp_path / "run.log"
    with log.open("wb") as out:
        started = time.monotonic()
        child = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                "tests/test_unitree_dds_edge.py", "-k", "sport_request_flood"],
                               cwd=REPO, stdout=out, stderr=subprocess.STDOUT, timeout=300)
    text = log.read_text(errors="replace")
    assert child.returncode == 0, text[-3000:]
    result = check(log)
    assert result.returncode == 0, (result.stderr, time.monotonic() - started)
    # Nothing at all after pytest's summary line: a spinning participant would print there.
    assert text.rstrip().splitlines()[-1].startswith("1 passed"), text[-2000:]
