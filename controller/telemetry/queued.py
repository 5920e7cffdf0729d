"""A slow sink (compression, the disk, fsync) on a thread of its own, behind a bounded
queue, so that the sample loop only ever pays for a ``put``.

When the queue is full: in virtual time the loop waits for the sink (nothing is lost and
sample time simply does not advance meanwhile); in real time the item is dropped and
counted, because a loop that waits on a disk misses its samples and its safety checks.
The count is in ``status`` (``sinks``) and in the log. A failure of the wrapped sink is
raised at the next call from the loop, where the telemetry drops the sink as it would
drop the sink itself.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from typing import Any

from fluidsense.common.samples import SampleBlock
from fluidsense.drivers.sampler.realtime import share_loop_priority

from .fanout import Sink

log = logging.getLogger(__name__)

#: items waiting for the sink: at 100 blocks per second (1 kHz, blocks of 10) about 40 s
#: of a stalled disk before anything is dropped
QUEUE_ITEMS = 4096
_CLOSE = object()


class QueuedSink(Sink):
    def __init__(self, inner: Sink, *, wait_when_full: bool, maxsize: int = QUEUE_ITEMS) -> None:
        """``wait_when_full``: True in virtual time (lose nothing), False in real time
        (never stall the loop: drop and count)."""
        self.inner, self.name = inner, type(inner).__name__
        self._wait = wait_when_full
        self._q: queue.Queue[Any] = queue.Queue(maxsize)
        self.dropped = 0
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, name=f"sink-{self.name}", daemon=True)
        self._thread.start()

    @property
    def stats(self) -> dict[str, Any]:
        return {"sink": self.name, "queued": self._q.qsize(), "dropped": self.dropped}

    # ------------------------------------------------------------ the loop's side
    def on_block(self, block: SampleBlock) -> None:
        self._put(("on_block", block))

    def on_event(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self._put(("on_event", topic, t_s, payload))

    def flush(self, t_s: float) -> None:
        self._put(("flush", t_s))

    def wait_idle(self) -> None:
        """Return once everything queued so far has been handled (tests, and a caller that
        wants the disk to hold what the loop has seen)."""
        self._q.join()

    def close(self) -> None:
        """Everything queued written, then the sink closed; waits for the thread."""
        if self._thread.is_alive():
            self._put_waiting(_CLOSE)
            self._thread.join()
        if self.dropped:
            log.warning("%s: %d items were dropped while its queue was full", self.name, self.dropped)
        self._raise_failure()

    def _put(self, item: Any) -> None:
        self._raise_failure()
        if self._wait:
            self._put_waiting(item)
            return
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 1000 == 0:
                log.warning("%s cannot keep up: %d items dropped so far", self.name, self.dropped)

    def _put_waiting(self, item: Any) -> None:
        while True:  # a sink that died while the queue was full must not hold the loop for ever
            try:
                self._q.put(item, timeout=0.1)
                return
            except queue.Full:
                self._raise_failure()

    def _raise_failure(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            with contextlib.suppress(queue.Full):  # the telemetry drops this sink now: end the thread
                self._q.put_nowait(_CLOSE)
            raise error

    # ------------------------------------------------------------ the thread's side
    def _work(self) -> None:
        share_loop_priority()  # it takes the GIL and the queue's lock the loop takes
        failed = False
        while True:
            item = self._q.get()
            try:
                if item is _CLOSE:
                    if not failed:
                        self._call("close")
                    return
                if failed:  # lost with the sink; the loop hears of the failure at its next call
                    self.dropped += 1
                    continue
                method, *args = item
                failed = not self._call(method, *args)
            finally:
                self._q.task_done()

    def _call(self, method: str, *args: Any) -> bool:
        try:
            getattr(self.inner, method)(*args)
        except Exception as exc:  # noqa: BLE001 - raised to the loop at its next call
            self._error = exc
            return False
        return True
