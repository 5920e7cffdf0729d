"""Stop signals: SIGINT, SIGTERM and SIGHUP all stop a process that can move a valve the
same way, through its vent path.

Ctrl-C is not the only way a job is stopped: systemd, ``docker stop``, ``timeout`` and CI
runners send SIGTERM, and a closed terminal or SSH session sends SIGHUP. Python's default
for both is to die at once, which leaves the valves where the last command put them (a
gripper held inflated until something else vents it). Here each of the three becomes one
cancellation of the job: the code that unwinds (the controller's stop, check's finish)
vents and confirms, then the caller says what was done and exits with ``exit_code``.

Used by the daemon (``handle_stop_signals`` around its run: a stop signal is its normal
stop) and the CLI jobs (``run``: asyncio.run whose main task a stop signal cancels), and
by synchronous programs such as the examples (``raise_on_stop_signals``: SIGTERM and
SIGHUP raise as Ctrl-C does).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from collections.abc import Callable, Coroutine, Iterator
from typing import Any, TypeVar

from .errors import FluidsenseError

log = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

T = TypeVar("T")


def exit_code(signum: int) -> int:
    """The shell's convention, 128 + the signal's number: 130 SIGINT, 129 SIGHUP, 143
    SIGTERM. A supervisor or a script tells from it what stopped the job."""
    return 128 + int(signum)


class StopSignal(KeyboardInterrupt):
    """A stop signal ended the job after it had unwound (vented). A KeyboardInterrupt,
    not a FluidsenseError: it is not a failure, and every path that already handles
    Ctrl-C (keep the journal, never catch it as an error) handles the others alike."""

    def __init__(self, signum: int, at: float | None = None):
        self.signum = signal.Signals(signum)
        #: time.monotonic() when the signal was handled: read-backs after it count as confirmation
        self.at = time.monotonic() if at is None else at
        super().__init__(self.name)

    @property
    def name(self) -> str:
        return self.signum.name

    @property
    def exit_code(self) -> int:
        return exit_code(self.signum)


def interruption(exc: KeyboardInterrupt) -> StopSignal:
    """A plain KeyboardInterrupt (Python's own SIGINT handler) as the StopSignal it is."""
    return exc if isinstance(exc, StopSignal) else StopSignal(signal.SIGINT)


@contextlib.contextmanager
def handle_stop_signals(loop: asyncio.AbstractEventLoop,
                        on_stop: Callable[[StopSignal], None]) -> Iterator[list[StopSignal]]:
    """While inside, the first stop signal calls ``on_stop`` (in the loop, between two of
    its steps); later ones are logged and ignored, so that a second Ctrl-C or a repeated
    SIGTERM cannot cut the venting short (SIGKILL still can; a box watchdog covers that).
    Yields the list that holds the signal once one came."""
    received: list[StopSignal] = []

    def on_signal(signum: int) -> None:
        if received:
            log.warning("%s while stopping on %s: already venting and closing", signal.Signals(signum).name,
                        received[0].name)
            return
        received.append(StopSignal(signum))
        log.warning("%s received: stopping, venting first", received[0].name)
        on_stop(received[0])

    installed = []
    try:
        for sig in STOP_SIGNALS:
            loop.add_signal_handler(sig, on_signal, sig)
            installed.append(sig)
        yield received
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)


def run(job: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(job)`` where SIGINT, SIGTERM and SIGHUP cancel ``job``; once it has
    unwound (its ``async with`` blocks closed: the controller vented) StopSignal is
    raised. A job that finishes before the cancellation reaches it returns its result."""
    received: list[StopSignal] = []

    async def main() -> T:
        task = asyncio.current_task()
        assert task is not None
        with handle_stop_signals(asyncio.get_running_loop(), lambda _: task.cancel()) as got:
            try:
                return await job
            finally:
                received.extend(got)

    try:
        return asyncio.run(main())
    except asyncio.CancelledError:
        if received:
            raise received[0] from None
        raise
    except FluidsenseError as exc:
        # a job that turns its cancellation into an error of its own (its cycle "aborted:
        # shutdown") was still stopped by the signal: that is what the caller must hear
        if received:
            raise received[0] from exc
        raise


@contextlib.contextmanager
def raise_on_stop_signals() -> Iterator[None]:
    """Synchronous code (no event loop): SIGTERM and SIGHUP raise StopSignal in the main
    thread as Ctrl-C raises KeyboardInterrupt, so ``finally`` and ``except
    KeyboardInterrupt`` blocks release what the program holds; later signals are
    ignored (logged) so that they cannot cut that release short. Main thread only."""
    received: list[StopSignal] = []

    def on_signal(signum: int, _frame: Any) -> None:
        if received:
            log.warning("%s while stopping on %s: already releasing", signal.Signals(signum).name, received[0].name)
            return
        received.append(StopSignal(signum))
        raise received[0]

    before = {sig: signal.signal(sig, on_signal) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
