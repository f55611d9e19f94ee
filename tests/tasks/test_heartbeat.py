"""A stage that takes minutes says so at least once a minute: the heartbeat of tasks.common."""

from __future__ import annotations

import logging
import time

from tasks.common import beating, heartbeat, logger

logger()  # Prefect configures logging when first asked for a logger: before caplog installs its handler


def test_a_long_block_logs_its_elapsed_time_and_status_until_it_ends(caplog):
    done = [0]
    with caplog.at_level(logging.INFO, logger="tasks"):
        with heartbeat("closure checks", lambda: f"{done[0]} of 8 candidates checked", every=0.05):
            for _ in range(4):
                time.sleep(0.08)
                done[0] += 1
        n = len(caplog.records)
        time.sleep(0.2)  # after the block, silence
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == n >= 4
    assert all(line.startswith("closure checks: still running, ") for line in lines)
    assert lines[-1].endswith(" of 8 candidates checked") and "0 of 8" in lines[0]
    elapsed = [float(line.split("still running, ")[1].split(" s")[0]) for line in lines]
    assert elapsed == sorted(elapsed)


def test_a_decorated_task_body_beats_and_returns_its_value(caplog, monkeypatch):
    monkeypatch.setenv("MRGP_HEARTBEAT_SECONDS", "0.05")

    @beating("decision")
    def slow(x):
        time.sleep(0.2)
        return 2 * x

    with caplog.at_level(logging.INFO, logger="tasks"):
        assert slow(21) == 42
    assert sum(r.getMessage().startswith("decision: still running") for r in caplog.records) >= 2
