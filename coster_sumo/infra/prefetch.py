"""A background thread that computes the next items of a loop while the current one is used."""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")
U = TypeVar("U")


def prefetch(fn: Callable[[T], U], items: Iterable[T], depth: int = 2) -> Iterator[U]:
    """``fn(item)`` for every item, computed by a background thread up to ``depth`` items ahead
    (numpy and torch release the GIL while copying: batch assembly overlaps the training step).
    Exceptions reach the consumer; leaving the loop early stops the thread."""
    q: queue.Queue[tuple[bool, Any]] = queue.Queue(maxsize=max(1, depth))
    stop = threading.Event()
    done = object()

    def work() -> None:
        try:
            for item in items:
                res = fn(item)
                while not stop.is_set():
                    try:
                        q.put((True, res), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((True, done))
        except BaseException as exc:  # handed to the consumer
            q.put((False, exc))

    thread = threading.Thread(target=work, name="coster-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            ok, value = q.get()
            if not ok:
                raise value
            if value is done:
                return
            yield value
    finally:
        stop.set()
