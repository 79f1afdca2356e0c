"""The order of work of one process serving many streams (sans-I/O: the caller passes the
clock, in ns of any monotonic clock).

Three rules, in this order:

1. **Drain before compute.** Work runs in turns of at most `budget_ns`; between turns the
   engine gives the event loop a pass, so the sources read their sockets (the kernel's
   receive buffer holds only tens of milliseconds of 32 streams' frames) before more is
   computed. A turn always does at least one step, so a single long call still ends.
2. **Due first, across streams.** Every queued frame's due decisions (`Pipeline.push`), of
   every stream, oldest arrival first (the queue is FIFO), run before any stream's deferred
   work (`Pipeline.idle`, a re-analysis that decides nothing due now).
3. **Deferred work oldest first**, one stream per step; a stream's own order is kept: the
   engine runs a stream's pending deferred work before that stream's next push.

`TurnStats` measures it: turns, drains, the longest turn, the deferred work run early (by
rule 3's stream order) and late (when nothing was due).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Generic, TypeVar

__all__ = ["Scheduler", "TurnStats", "DEFAULT_TURN_BUDGET_NS"]

DEFAULT_TURN_BUDGET_NS = 1_000_000  # 1 ms of work, then the sockets are read again

T = TypeVar("T")


@dataclass
class TurnStats:
    """What the scheduler did over a run."""

    turns: int = 0            # turns ended by the budget (each followed by a drain)
    longest_turn_ms: float = 0.0
    deferred_in_order: int = 0  # deferred work run before its stream's next push
    deferred_idle: int = 0      # deferred work run when nothing was due

    def as_dict(self) -> dict[str, float | int]:
        """Plain counters (JSON-ready)."""
        return {"turns": self.turns, "longest_turn_ms": round(self.longest_turn_ms, 3),
                "deferred_in_order": self.deferred_in_order,
                "deferred_idle": self.deferred_idle}


class Scheduler(Generic[T]):
    """Deferred work per stream (oldest first) and the turn budget (see the module)."""

    def __init__(self, budget_ns: int = DEFAULT_TURN_BUDGET_NS) -> None:
        self.budget_ns = budget_ns
        self.stats = TurnStats()
        self._deferred: OrderedDict[str, T] = OrderedDict()
        self._turn_start: int | None = None

    # ------------------------------------------------------------------ turns

    def begin(self, now_ns: int) -> None:
        """A step of work starts at `now_ns` (opens a turn if none is open)."""
        if self._turn_start is None:
            self._turn_start = now_ns

    def should_drain(self, now_ns: int) -> bool:
        """True when the open turn has used its budget: the caller lets the sources read
        (and calls `drained`) before the next step."""
        return self._turn_start is not None and now_ns - self._turn_start >= self.budget_ns

    def drained(self, now_ns: int) -> None:
        """The sources had their pass: the turn that ran until `now_ns` is over."""
        if self._turn_start is not None:
            self.stats.turns += 1
            self.stats.longest_turn_ms = max(self.stats.longest_turn_ms,
                                             (now_ns - self._turn_start) / 1e6)
        self._turn_start = None

    def waiting(self) -> None:
        """Nothing to do: the loop waits for input (the open turn ends unmeasured)."""
        self._turn_start = None

    # ------------------------------------------------------------------ deferred work

    def defer(self, name: str, item: T) -> None:
        """Stream `name` has deferred work (its newest frame's); queued behind the others."""
        self._deferred.pop(name, None)
        self._deferred[name] = item

    def take(self, name: str) -> T | None:
        """Stream `name`'s pending deferred work, before its next push (None if none)."""
        item = self._deferred.pop(name, None)
        if item is not None:
            self.stats.deferred_in_order += 1
        return item

    def drop(self, name: str) -> None:
        """Forget stream `name`'s deferred work (the stream ends or is replaced)."""
        self._deferred.pop(name, None)

    def next_deferred(self) -> T | None:
        """The oldest deferred work, when nothing is due (None if none)."""
        if not self._deferred:
            return None
        self.stats.deferred_idle += 1
        return self._deferred.popitem(last=False)[1]

    def __contains__(self, name: object) -> bool:
        return name in self._deferred

    def __len__(self) -> int:
        return len(self._deferred)
