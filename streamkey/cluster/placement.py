"""Where a cluster run keeps things in Redis (`RedisKeys`) and which shard serves which
stream id (`Placement`: load-balanced once, atomically in Redis, stable for the run)."""

from __future__ import annotations

from typing import Any

__all__ = ["RedisKeys", "Placement"]


class RedisKeys:
    """Key names of one cluster run (`--run NAME` keeps several runs apart in one Redis)."""

    def __init__(self, run: str) -> None:
        self.prefix = f"streamkey:{run}"
        self.events = f"{self.prefix}:events"
        self.event_ids = f"{self.prefix}:event-ids"

    def log(self, stream: str) -> str:
        """Redis Stream of the stream's frames."""
        return f"{self.prefix}:log:{stream}"

    def snapshot(self, stream: str) -> str:
        """Hash {data, seq, frames} of the stream's last snapshot (frames: pushed so far)."""
        return f"{self.prefix}:snap:{stream}"

    def skeleton(self, stream: str) -> str:
        """Hash {bvh, fps} of the stream's skeleton."""
        return f"{self.prefix}:skel:{stream}"

    def shard(self, shard: int) -> str:
        """Set of the stream ids of one shard."""
        return f"{self.prefix}:shard:{shard}"

    def starts(self, shard: int) -> str:
        """How often the shard's worker started (1 + restarts)."""
        return f"{self.prefix}:starts:{shard}"

    @property
    def placement(self) -> str:
        """Hash {stream id: shard} of every id placed in this run."""
        return f"{self.prefix}:placement"

    @property
    def placed(self) -> str:
        """Hash {shard: stream ids placed on it}."""
        return f"{self.prefix}:placed"

    def totals(self, shard: int) -> str:
        """Hash {events, duplicates, frames (of retired streams)} of a shard, kept across
        its worker's restarts."""
        return f"{self.prefix}:totals:{shard}"



# Atomic placement: an id placed before keeps its shard; a new one goes to the least placed.
_PLACE = """
local got = redis.call('HGET', KEYS[1], ARGV[1])
if got then return tonumber(got) end
local best, fewest = 0, nil
for shard = 0, tonumber(ARGV[2]) - 1 do
  local n = tonumber(redis.call('HGET', KEYS[2], tostring(shard)) or '0')
  if fewest == nil or n < fewest then best, fewest = shard, n end
end
redis.call('HSET', KEYS[1], ARGV[1], best)
redis.call('HINCRBY', KEYS[2], tostring(best), 1)
return best
"""


class Placement:
    """Which shard owns a stream id (see the module): placed once in Redis, load-balanced by
    count, then cached in this process (an id never moves within a run)."""

    def __init__(self, redis: Any, keys: RedisKeys, shards: int) -> None:
        self.redis, self.keys, self.shards = redis, keys, shards
        self._place = redis.register_script(_PLACE)
        self._known: dict[str, int] = {}

    def known(self, stream: str) -> int | None:
        """The shard of `stream` if this process has looked it up (no Redis call)."""
        return 0 if self.shards == 1 else self._known.get(stream)

    def shard(self, stream: str) -> int:
        """The shard of `stream`, placing it now if no process has."""
        found = self.known(stream)
        if found is None:
            found = self._known[stream] = int(self._place(
                keys=[self.keys.placement, self.keys.placed], args=[stream, self.shards]))
        return found

    def place(self, streams: list[str]) -> list[int]:
        """Place these ids in this order (round robin on a fresh run); their shards."""
        return [self.shard(s) for s in streams]
