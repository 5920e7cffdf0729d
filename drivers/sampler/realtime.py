"""Real-time settings of the sampler thread, each applied when the system permits it.

All of them concern the calling thread only (pid 0 in sched_* and prctl mean "this
thread"), on purpose: the ZeroMQ I/O thread, started before these are applied, keeps
the normal policy and may run on any CPU, so moving blocks to the daemon never
competes with the slot loop at real-time priority.

Except the poller's own threads (``poller_threads``: those its ``open()`` started, such
as ur_rtde's RTDE receive thread), which get the same SCHED_FIFO priority, unpinned. The
slot loop reads what they receive: at normal priority beside two busy processes they
got a third of a CPU in slices, the newest RTDE package was often not yet parsed when
its slot came (a missed slot), and the mutex a getter shares with them could be held by
a thread the scheduler had put aside (docs/performance.md, "The ur driver under load").

Each setting is reported as ``{"applied": bool, "requested": bool, "detail": str}``; when one is not
applied the process logs one warning line saying what and why (e.g. EPERM).
"""

from __future__ import annotations

import ctypes
import errno
import gc
import logging
import os
import sys
from typing import Any

log = logging.getLogger(__name__)

PR_SET_TIMERSLACK = 29  # <linux/prctl.h>
PR_GET_TIMERSLACK = 30

Report = dict[str, dict[str, Any]]


def _result(applied: bool, detail: str, requested: bool = True) -> dict[str, Any]:
    return {"applied": applied, "requested": requested, "detail": detail}


def _os_reason(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno or 0, "?")
    return f"{exc.strerror or exc} ({name})"


def _rt_runtime() -> str:
    try:
        with open("/proc/sys/kernel/sched_rt_runtime_us") as f:
            return f.read().strip()
    except OSError:
        return "unknown"


def set_fifo(priority: int | None, reset_on_fork: bool = False) -> dict[str, Any]:
    """``reset_on_fork``: processes this thread starts get the normal policy back (the
    daemon starts helpers that set their own, or none)."""
    if priority is None:
        return _result(False, "not requested (rt_priority: null)", requested=False)
    if not hasattr(os, "sched_setscheduler"):
        return _result(False, f"SCHED_FIFO is not available on {sys.platform}")
    policy = os.SCHED_FIFO | (os.SCHED_RESET_ON_FORK if reset_on_fork else 0)
    try:
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except OSError as exc:
        hint = ""
        if exc.errno == errno.EPERM:
            hint = (f": needs CAP_SYS_NICE or RLIMIT_RTPRIO >= {priority} (ulimit -r), and in a "
                    "container a runtime that allows real-time scheduling")
        return _result(False, f"SCHED_FIFO priority {priority} refused: {_os_reason(exc)}{hint}")
    return _result(True, f"SCHED_FIFO priority {priority} (kernel RT budget sched_rt_runtime_us={_rt_runtime()})")


#: the SCHED_FIFO priority the daemon's sample loop was granted (set_loop_priority); None
#: while it runs at normal priority
_loop_priority: int | None = None


def set_loop_priority(priority: int | None) -> dict[str, Any]:
    """The daemon's (or a CLI job's) sample loop thread at SCHED_FIFO ``priority``; the
    processes it starts get the normal policy back (SCHED_RESET_ON_FORK), and so, on
    Linux, do the threads it starts: they are clones too. Its own threads that take the
    GIL or a lock the loop takes (the recording's) call ``share_loop_priority``."""
    global _loop_priority
    result = set_fifo(priority, reset_on_fork=True)
    if result["applied"]:
        _loop_priority = priority
    return result


def release_loop_priority() -> None:
    """The calling thread back at normal priority, the loop's priority forgotten: for a
    library caller (a test, a bench) that ran a controller's loop the way the daemon does
    (``set_loop_priority``) and goes on with other work in the same thread."""
    global _loop_priority
    _loop_priority = None
    if hasattr(os, "sched_setscheduler"):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def share_loop_priority() -> None:
    """The calling thread, one of the loop's process's own, at the loop's priority when the
    loop has one. A thread at normal priority that holds the GIL (or the queue's lock)
    while two busy processes share the CPUs is put aside for tens to hundreds of ms, and
    the loop, which needs the GIL next, waits with it (docs/performance.md, "The overrun as
    load starts")."""
    if _loop_priority is not None:
        result = set_fifo(_loop_priority, reset_on_fork=True)
        if not result["applied"]:
            log.warning("a thread of the sample loop's process stays at normal priority: %s", result["detail"])


def pin(cpu: int | str) -> dict[str, Any]:
    if cpu == "none":
        return _result(False, "not requested (cpu: none)", requested=False)
    if not hasattr(os, "sched_setaffinity"):
        return _result(False, f"CPU affinity is not available on {sys.platform}")
    allowed = sorted(os.sched_getaffinity(0))
    # CPU 0 usually takes most interrupts and housekeeping: by default take the last one
    target = allowed[-1] if cpu == "auto" else int(cpu)
    if target not in allowed:
        return _result(False, f"CPU {target} is not in this process's allowed set {allowed}")
    try:
        os.sched_setaffinity(0, {target})
    except OSError as exc:
        return _result(False, f"pinning to CPU {target} refused: {_os_reason(exc)}")
    return {**_result(True, f"pinned to CPU {target} of {allowed}"), "cpu": target}


def set_timerslack(slack_ns: int = 1) -> dict[str, Any]:
    if not sys.platform.startswith("linux"):
        return _result(False, f"PR_SET_TIMERSLACK is Linux only (this is {sys.platform})")
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        rc = libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), ctypes.c_ulong(0),
                        ctypes.c_ulong(0), ctypes.c_ulong(0))
    except (OSError, AttributeError) as exc:
        return _result(False, f"prctl unavailable: {exc}")
    if rc != 0:
        err = ctypes.get_errno()
        return _result(False, f"prctl(PR_SET_TIMERSLACK, {slack_ns}) failed: {os.strerror(err)} "
                       f"({errno.errorcode.get(err, '?')})")
    now = libc.prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0)
    # the kernel ignores the slack of real-time threads; it matters when SCHED_FIFO is refused
    return _result(True, f"timer slack {now} ns")


def freeze_gc() -> dict[str, Any]:
    # Objects alive now (modules, the poller) are moved out of the collector's reach;
    # with collection off, no pause can land in the loop. The loop creates no cycles.
    gc.collect()
    gc.freeze()
    gc.disable()
    return _result(True, f"gc.freeze() ({gc.get_freeze_count()} objects) + gc.disable()")


def threads() -> set[int]:
    """This process's thread ids (Linux: /proc/self/task); empty where it cannot be read."""
    try:
        return {int(tid) for tid in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def set_fifo_threads(tids: set[int], priority: int | None) -> dict[str, Any]:
    """SCHED_FIFO for other threads of this process (sched_setscheduler takes a thread id)."""
    if not tids:
        return _result(False, "none started by the poller", requested=False)
    if priority is None:
        return _result(False, "not requested (rt_priority: null)", requested=False)
    if not hasattr(os, "sched_setscheduler"):
        return _result(False, f"SCHED_FIFO is not available on {sys.platform}")
    done = []
    for tid in sorted(tids):
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except ProcessLookupError:
            continue  # a thread that has ended since
        except OSError as exc:
            return _result(False, f"SCHED_FIFO priority {priority} for the poller's thread {tid} refused: "
                           f"{_os_reason(exc)}")
        done.append(tid)
    return {**_result(True, f"the poller's {len(done)} thread(s) at SCHED_FIFO priority {priority}"), "tids": done}


def apply(priority: int | None, cpu: int | str, timerslack_ns: int = 1,
          poller_threads: set[int] = frozenset()) -> Report:
    """Apply everything, in an order that lets each step still succeed after the others.
    ``poller_threads``: the threads the poller started (``threads()`` around its open())."""
    report = {
        "timerslack": set_timerslack(timerslack_ns),
        "affinity": pin(cpu),
        "sched_fifo": set_fifo(priority),
        "poller_threads": set_fifo_threads(set(poller_threads), priority),
        "gc": freeze_gc(),
    }
    for name, r in report.items():
        if r["requested"] and not r["applied"]:
            log.warning("%s not applied: %s", name, r["detail"])
    applied = ", ".join(r["detail"] for r in report.values() if r["applied"])
    log.info("real-time settings: %s", applied or "none applied")
    return report
