"""A shard's snapshot writer: the state is taken between two pushes, then compressed and
stored on one thread, in order (zlib releases the GIL), so a stream's next frames do not
wait for it."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

__all__ = ["Sealer"]


class Sealer:
    """One thread running snapshot stores in the order they were handed over."""

    def __init__(self, shard: int) -> None:
        self._thread = ThreadPoolExecutor(1, thread_name_prefix=f"streamkey-seal-{shard}")
        self._pending: list[Future[None]] = []

    def submit(self, store: Callable[[], None]) -> None:
        """Run `store` after every store handed over before it."""
        self._pending.append(self._thread.submit(store))

    def wait(self) -> None:
        """Wait for every store handed over so far; a failed one raises here."""
        pending, self._pending = self._pending, []
        for future in pending:
            future.result()

    def close(self) -> None:
        """Wait for the pending stores, then end the thread."""
        self.wait()
        self._thread.shutdown()
