"""Loaded by every Python process of a ``lab bench suite-cpu`` run (this folder is on its
PYTHONPATH): at exit, or at ``os._exit`` (the sampler and the ur_rtde worker end so), one
line with the process's pid, command and CPU in ``$FLUIDSENSE_SUITECPU_DIR/procs.jsonl``."""

import atexit
import json
import os
import resource
import sys

_OUT = os.environ["FLUIDSENSE_SUITECPU_DIR"]
_done = False


def _report():
    global _done
    if _done:
        return
    _done = True
    r = resource.getrusage(resource.RUSAGE_SELF)
    try:
        with open(os.path.join(_OUT, "procs.jsonl"), "a") as f:
            f.write(json.dumps({"pid": os.getpid(), "argv": list(getattr(sys, "orig_argv", sys.argv))[:4],
                                "cpu_s": r.ru_utime + r.ru_stime}) + "\n")
    except OSError:
        pass


_exit = os._exit


def _exit_reporting(code):
    _report()
    _exit(code)


atexit.register(_report)
os._exit = _exit_reporting
