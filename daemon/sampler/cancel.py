"""One check shared by the sampler's loops and its capture path: a cancel still pending."""

from __future__ import annotations

import asyncio


def raise_if_cancelled() -> None:
    """Raise :class:`asyncio.CancelledError` when the current task has a cancel pending.

    Our own waits use ``asyncio.timeout``, which never loses a cancel; a driver library's
    internal ``asyncio.wait_for`` (Python 3.11) can still swallow one that arrives as the awaited
    read completes: the call returns normally and the task runs on with its cancel request still
    counted (``Task.cancelling()``). The poll loops check this at the top of every cycle, so
    :meth:`Sampler.stop` never waits on a loop that missed its cancel, and a capture checks it
    before it stores, so a cancelled capture stores nothing."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError
