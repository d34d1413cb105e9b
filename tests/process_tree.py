"""Processes started by a process, read from Linux's /proc (for the kill tests)."""

from __future__ import annotations

import os
import time
from pathlib import Path


def descendants(pid: int) -> set[int]:
    """Process ids of every process below ``pid`` (children, their children, ...)."""
    found: set[int] = set()
    pending = [pid]
    while pending:
        current = pending.pop()
        for task in Path(f"/proc/{current}/task").glob("*"):
            try:
                children = (task / "children").read_text().split()
            except OSError:
                continue
            for child in map(int, children):
                if child not in found:
                    found.add(child)
                    pending.append(child)
    return found


def running(pid: int) -> bool:
    """Whether ``pid`` is a live process (not gone, not a zombie waiting to be reaped)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def wait_for_descendants(pid: int, count: int, timeout: float) -> set[int]:
    """The descendants of ``pid`` once there are at least ``count`` (or whatever there are at ``timeout``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = descendants(pid)
        if len(found) >= count:
            return found
        time.sleep(0.05)
    return descendants(pid)


def wait_until_gone(pids: set[int], timeout: float) -> set[int]:
    """The processes of ``pids`` still running after up to ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    alive = {p for p in pids if running(p)}
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = {p for p in alive if running(p)}
    return alive


def kill_all(pids: set[int]) -> None:
    """SIGKILL what is left (so a failing test leaves nothing behind)."""
    for pid in pids:
        try:
            os.kill(pid, 9)
        except OSError:
            pass


def sigkill_leaves_no_orphans(proc: object, workers: set[int]) -> None:
    """SIGKILL ``proc`` (a ``subprocess.Popen``) and assert that none of ``workers`` outlives it."""
    proc.kill()
    proc.wait()
    assert not wait_until_gone(workers, timeout=20), "worker processes outlived their parent"
