"""Refused input of a cluster run: the shards count it by kind and explain it at most every
`REPEAT_S` per kind, as lines in a Redis list the driver prints on stderr."""

from __future__ import annotations

import math
import time
from collections import Counter
from typing import Any

from .placement import RedisKeys

__all__ = ["InputNotes", "notices_key", "new_notices", "REPEAT_S"]

REPEAT_S = 5.0  # a kind of refusal is explained again at most this often


class InputNotes:
    """A shard's refused input: `counts` by kind, and when each kind was last explained."""

    def __init__(self, repeat_s: float = REPEAT_S) -> None:
        self.counts: Counter[str] = Counter()
        self.repeat_s = repeat_s
        self._said_at: dict[str, float] = {}

    def note(self, kind: str) -> bool:
        """Count one refusal of `kind`; True when it is to be explained now."""
        self.counts[kind] += 1
        now = time.monotonic()
        if now - self._said_at.get(kind, -math.inf) < self.repeat_s:
            return False
        self._said_at[kind] = now
        return True


def notices_key(run: str) -> str:
    """Redis list of the run's explanations of refused input (one line each)."""
    return f"{RedisKeys(run).prefix}:input-notices"


def new_notices(redis: Any, run: str, seen: int) -> list[str]:
    """The notice lines after the first `seen` (the driver prints them as they come)."""
    return [line.decode("utf-8", "replace") for line in
            redis.lrange(notices_key(run), seen, -1)]
