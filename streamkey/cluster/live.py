"""Live streams on many workers, the parts that do not need Ray: sharding, the Redis frame
log and snapshot store, event ids and the de-duplicating event sink, the per-shard worker.

Data path (Ray is never on it)::

    capture -> ZeroMQ PUB, topic = stream id -> ShardWorker (owns the ids placed on it)
                       |                              | Pipeline per stream (online.py)
                       v                              v
               FrameLogger -> Redis Stream per     events -> Redis Stream `events`
               (the driver)   stream (trimmed)     (de-duplicated by event id)
                                   ^
               snapshots every N frames, log replay after a restart

A worker that starts (first time, restarted by Ray, or re-created on another node) restores
each of its streams from its last snapshot and replays the logged frames after it; a hole in
the live stream (frames the worker did not receive) is filled from the log the same way. The
events this replays again carry the ids they had the first time, and the sink drops them.

Placement (`Placement`): a stream id is placed on the shard that has the fewest stream ids
placed so far (ties: the lowest shard), once, atomically in Redis, by whichever process sees
it first (the logger or a worker); it keeps that shard for the whole run, restarts included.
So ids are balanced whatever their names (8 ids over 2 shards: 4 + 4), and `--streams A,B,..`
places its ids in the order given (round robin) before any frame flows.

Counts survive restarts: the events a shard appended are counted in Redis by the same atomic
step that appends them (`RedisKeys.totals`), a stream's frame count is stored with its
snapshot (a restored stream counts on from there; the frames it replays are the ones the
snapshot does not cover), and a retired stream's frames move to the shard's totals in the same
transaction that forgets the stream.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zmq

from ..adapters.codec import event_json
from ..adapters.zmq import decode_frame_parts, decode_skeleton_parts, parse_topic, topic
from ..io import StreamSpec, stream_tag
from ..jit import warm_up
from ..keyframes import INPUT_STATUS, Event, StatusEvent
from ..motion import Frame, Skeleton
from ..online import Pipeline
from ..snapshot import pickled, seal
from ..streamtable import LiveStream, StreamTable, keyframers_for
from .notices import InputNotes, new_notices, notices_key
from .placement import Placement, RedisKeys
from .sealing import Sealer

__all__ = ["ClusterConfig", "ShardWorker", "Placement", "split_topic",
           "stream_topic", "snapshot_pipeline", "restore_pipeline", "RedisKeys",
           "notices_key", "new_notices"]

_LOG_BATCH = 512  # log entries per Redis round trip when replaying


@dataclass
class ClusterConfig:
    """Everything a shard worker and the frame logger need (pickled to the Ray actors)."""

    endpoint: str  # tcp://HOST:PORT of the frame publisher
    redis_url: str
    shards: int
    methods: list[str]
    params: dict[str, dict[str, Any]] = field(default_factory=dict)
    lookahead: int | None = None
    run: str = "default"
    snapshot_every: int = 600
    failover_seconds: float = 30.0
    stream_idle: float = 10.0
    streams: list[str] | None = None  # subscribe to these topics only (else all, filtered)
    skeleton: Skeleton | None = None  # --skeleton FILE: one skeleton for every stream
    skeleton_fps: float = 120.0


def split_topic(parts: list[bytes]) -> tuple[str, list[bytes]]:
    """(stream id, the message as an untagged one: `[b"frame" | b"skeleton", ...]`) of a
    message on the ZeroMQ wire format (`adapters.zmq.topic`: `STREAM/frame`, bare `frame` for
    stream `default`). Raises ValueError saying what is wrong."""
    if not parts:
        raise ValueError("empty message, expected a topic and a body")
    if len(parts) < 2:
        raise ValueError(f"message has {len(parts)} part(s), expected a topic and a body")
    try:
        kind, tag = parse_topic(parts[0])
    except LookupError as exc:
        raise ValueError(str(exc)) from None
    return tag or "default", [kind.encode(), *parts[1:]]


def stream_topic(stream: str, parts: list[bytes]) -> list[bytes]:
    """The untagged multipart message `parts` (a frame or skeleton) on the topic of `stream`."""
    return [topic(parts[0].decode(), stream), *parts[1:]]


def subscriptions(streams: list[str] | None) -> list[bytes]:
    """ZeroMQ SUB prefixes for these stream ids (every topic without)."""
    if not streams:
        return [b""]
    out: list[bytes] = []
    for stream in streams:
        out += [b"frame", b"skeleton"] if stream_tag(stream) is None else [
            f"{stream}/".encode()]
    return out


def snapshot_pipeline(pipeline: Pipeline) -> bytes:
    """The pipeline's state as versioned snapshot bytes (`Pipeline.snapshot`)."""
    return pipeline.snapshot()


def restore_pipeline(data: bytes) -> Pipeline:
    """The pipeline of `snapshot_pipeline(...)` bytes (`Pipeline.restore`)."""
    return Pipeline.restore(data)


# Atomic "append unless seen, and count": a worker killed between the steps loses nothing.
_EMIT = """
local added = 0
for i = 1, #ARGV, 2 do
  if redis.call('SADD', KEYS[2], ARGV[i]) == 1 then
    redis.call('XADD', KEYS[1], '*', 'id', ARGV[i], 'event', ARGV[i + 1])
    added = added + 1
  end
end
redis.call('HINCRBY', KEYS[3], 'events', added)
redis.call('HINCRBY', KEYS[3], 'duplicates', #ARGV / 2 - added)
return added
"""

def _redis(url: str) -> Any:
    import redis

    return redis.Redis.from_url(url, socket_timeout=10, socket_connect_timeout=10)


def parse_skeleton_message(body: list[bytes]) -> tuple[Skeleton, float, str]:
    """(skeleton, fps, BVH text) of a `[b"skeleton", JSON]` body; raises ValueError only."""
    try:
        return decode_skeleton_parts(body)
    except ValueError:
        raise
    except Exception as exc:  # any failure of a hostile skeleton is the message's fault
        raise ValueError(f"{type(exc).__name__}: {exc}") from None


@dataclass
class _Stream:
    """A stream of this shard: its entry in the stream table, and its log and snapshot
    bookkeeping."""

    live: LiveStream
    since_snapshot: int = 0
    frames: int = 0                 # frames pushed, each once (restored from its snapshot)
    replayed_to: int | None = None  # live frames up to this seq came from the log already

    @property
    def pipeline(self) -> Pipeline:
        """The stream's pipeline."""
        return self.live.pipeline


class ShardWorker:
    """One shard: the streams placed on `shard`, one `Pipeline` each, fed from the
    ZeroMQ publisher directly, snapshotted to Redis, events to the Redis sink.

    Its streams live in a `StreamTable` (idle streams retired after `stream_idle`), under the
    table's fault policy: a keyframer that raises restarts the stream's windows and leaves a
    status event "error" in the event log.

    `handle(parts)` takes one ZeroMQ message and never raises (every message that does not
    become a frame is counted by kind); `start()` runs the receive loop on a thread."""

    def __init__(self, config: ClusterConfig, shard: int) -> None:
        self.cfg = config
        self.shard = shard
        self.keys = RedisKeys(config.run)
        self.redis = _redis(config.redis_url)
        self._emit = self.redis.register_script(_EMIT)
        self.placement = Placement(self.redis, self.keys, config.shards)
        self.starts = int(self.redis.incr(self.keys.starts(shard)))
        self.table = StreamTable(idle=config.stream_idle)
        self.streams: dict[str, _Stream] = {}
        self.counters: Counter[str] = Counter()
        self.rejects: Counter[str] = Counter()
        self.retired: list[str] = []
        self.errors: list[str] = []
        self.lock = threading.Lock()
        self.ready = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._adopt_tried: dict[str, float] = {}
        self.input_notes = InputNotes()  # refused input by kind, when last explained
        self._sealer = Sealer(shard)  # snapshots compressed and stored off the loop

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> None:
        """Subscribe, restore this shard's streams from Redis, then serve on a thread."""
        self._thread = threading.Thread(target=self._serve, name=f"streamkey-shard-{self.shard}",
                                        daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context.instance()
        sock = ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVHWM, 100_000)  # frames wait here while the log is replayed
        wanted = [s for s in self.cfg.streams or [] if self.placement.shard(s) == self.shard]
        for prefix in subscriptions(wanted) if self.cfg.streams else [b""]:
            sock.setsockopt(zmq.SUBSCRIBE, prefix)
        sock.connect(self.cfg.endpoint)
        try:
            with self.lock:
                self.restore_all()
            warm_up()  # compiled kernels loaded before the first stream's first frame
            self.ready.set()
            poller = zmq.Poller()
            poller.register(sock, zmq.POLLIN)
            while not self._stop.is_set():
                drained = True
                if poller.poll(100):
                    with self.lock:
                        for _ in range(256):
                            try:
                                parts = sock.recv_multipart(zmq.NOBLOCK)
                            except zmq.Again:
                                break
                            self.handle(parts)
                        else:
                            drained = False
                # Idle only once every received frame is pushed: a frame queued behind a
                # slow push (a snapshot, a burst) has arrived, its stream is not idle.
                if drained:
                    with self.lock:
                        self.retire_idle()
        except Exception as exc:  # Redis gone, socket failed: Ray restarts the actor
            self.errors.append(f"{type(exc).__name__}: {exc}")
            raise
        finally:
            sock.close(linger=0)

    def stop(self) -> dict[str, Any]:
        """End the run: stop receiving, decide everything pending (flush), return status."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)
        with self.lock:
            for stream in list(self.streams):
                self.retire(stream)
        self._sealer.close()
        return self.status()

    def status(self) -> dict[str, Any]:
        """Counters, streams and restarts of this shard (plain data). `counters` are this
        worker's since it started, except `frames`, `events` and `duplicates_dropped`: the
        shard's over the whole run (`totals()`, restarts included)."""
        with self.lock:
            totals = self.totals()
            streams = {s: {"frames": st.frames, "last_seq": _last_seq(st.pipeline)}
                       for s, st in self.streams.items()}
            return {"shard": self.shard, "starts": self.starts, "streams": streams,
                    "totals": totals,
                    "retired": list(self.retired), "counters": {**self.counters, **totals},
                    "rejects": dict(self.rejects), "errors": list(self.errors),
                    "input_problems": dict(self.input_notes.counts),
                    "keyframer_errors": self.table.faults.count,
                    "keyframer_faults": list(self.table.faults.messages)}

    def totals(self) -> dict[str, int]:
        """Frames and events of this shard over the whole run, restarts included: frames of
        its retired streams plus its live streams' (each frame once, replays included once),
        events appended and duplicates dropped (counted in Redis as they are appended)."""
        stored = {k.decode(): int(v) for k, v in
                  self.redis.hgetall(self.keys.totals(self.shard)).items()}
        return {"frames": stored.get("frames", 0) + sum(st.frames for st in
                                                         self.streams.values()),
                "events": stored.get("events", 0),
                "duplicates_dropped": stored.get("duplicates", 0)}

    # -- messages --------------------------------------------------------------------------
    def handle(self, parts: list[bytes]) -> None:
        """One ZeroMQ message; never raises, counts every message that is not a frame."""
        self.counters["messages"] += 1
        try:
            stream, body = split_topic(parts)
            owner = self.placement.known(stream)
            if owner is not None and owner != self.shard:
                self.counters["other_shards"] += 1  # subscribed to all topics: not ours
                return
            if body[0] == b"skeleton":
                skeleton, fps, _ = parse_skeleton_message(body)
                if self.placement.shard(stream) != self.shard:
                    self.counters["other_shards"] += 1
                elif stream not in self.streams:
                    self._create(stream, skeleton, fps)
                return
            if body[0] != b"frame":
                raise LookupError(f"unknown message kind {body[0][:32]!r}")
            frame = decode_frame_parts(body)
            if owner is None and self.placement.shard(stream) != self.shard:
                self.counters["other_shards"] += 1  # a valid frame: its id is placed now
                return
        except LookupError as exc:
            self._reject("topic", exc)
            return
        except (ValueError, TypeError, IndexError, RecursionError) as exc:
            self._reject("malformed", exc)
            return
        st = self.streams.get(stream) or self._adopt(stream)
        if st is None:
            # No skeleton yet: the logger keeps the frame, replayed when the skeleton comes.
            self.counters["before_skeleton"] += 1
            self._explain("no_skeleton", stream, f"frames on stream {stream!r} before any "
                          "skeleton: publish its skeleton message first, or give --skeleton "
                          "FILE; the frame log keeps them until it comes")
            return
        if st.replayed_to is not None:
            if frame.seq <= st.replayed_to:  # queued while the log was replayed: done already
                self.counters["live_already_replayed"] += 1
                return
            st.replayed_to = None
        last = _last_seq(st.pipeline)
        if last is not None and last + 1 < frame.seq:
            self.counters["holes"] += 1
            self.catch_up(stream, frame.seq)
        self.table.touch(st.live, time.monotonic())
        invalid = st.pipeline.guard.counters.invalid
        self._push(stream, st, frame)
        if st.pipeline.guard.counters.invalid > invalid:
            n = st.pipeline.guard.n_channels
            self._explain("channels" if np.size(frame.channels) != n else "invalid", stream,
                          f"frame with {np.size(frame.channels)} values on stream {stream!r}: "
                          f"expected {n} finite channel values (one per skeleton channel) "
                          "and a usable seq/time; dropped")

    def _reject(self, kind: str, exc: BaseException) -> None:
        self.rejects[kind] += 1
        if len(self.errors) < 20:
            self.errors.append(f"{kind}: {type(exc).__name__}: {str(exc)[:200]}")
        hint = ("; expected the topic <stream>/frame or <stream>/skeleton (bare frame or "
                "skeleton: stream default)" if "topic" in str(exc) or kind == "topic" else "")
        self._explain(kind, None, f"input refused ({kind}): {str(exc)[:200]}{hint}")

    def _explain(self, kind: str, stream: str | None, message: str) -> None:
        """Refused input, counted by kind and explained at most every `REPEAT_S` per kind
        (`InputNotes`): a status event `input_<kind>` in the event stream, and the line in
        the run's notice list (`notices_key`), which the driver prints on stderr."""
        if not self.input_notes.note(kind):
            return
        st = self.streams.get(stream) if stream is not None else None
        seq = _last_seq(st.pipeline) if st is not None else None
        detail: dict[str, Any] = {"kind": kind, "message": message, "shard": self.shard}
        if seq is not None:
            detail["seq"] = seq
        try:
            self.emit([StatusEvent(stream=stream or "*", method="*",
                                   status=INPUT_STATUS + kind, detail=detail, seq=seq)])
            self.redis.rpush(notices_key(self.cfg.run), f"shard {self.shard}: {message}")
        except Exception as exc:  # an explanation must never end the worker's loop
            if len(self.errors) < 20:
                self.errors.append(f"notice: {type(exc).__name__}: {exc}")

    # -- streams ---------------------------------------------------------------------------
    def _new_pipeline(self, spec: StreamSpec) -> Pipeline:
        keyframers = keyframers_for(spec, self.cfg.methods, self.cfg.params,
                                    self.cfg.lookahead)
        return Pipeline(keyframers, stream=spec.stream)

    def _open(self, stream: str, pipeline: Pipeline) -> _Stream:
        st = self.streams[stream] = _Stream(
            self.table.open(stream, stream, pipeline, time.monotonic()))
        return st

    def _create(self, stream: str, skeleton: Skeleton, fps: float) -> _Stream | None:
        """A new stream: its pipeline, a first snapshot, and every frame logged before it."""
        try:
            pipeline = self._new_pipeline(StreamSpec(stream, skeleton, fps))
        except Exception as exc:  # a skeleton the keyframers cannot use: counted, ignored
            self._reject("skeleton", exc)
            return None
        st = self._open(stream, pipeline)
        self.redis.sadd(self.keys.shard(self.shard), stream)
        self._snapshot(stream, st)
        self.catch_up(stream, None)
        self.counters["streams"] += 1
        return st

    def _adopt(self, stream: str) -> _Stream | None:
        """A frame of a stream whose skeleton this worker missed: the logger's copy (or
        `--skeleton`), looked up at most twice a second per stream."""
        now = time.monotonic()
        if now - self._adopt_tried.get(stream, -1.0) < 0.5:
            return None
        self._adopt_tried[stream] = now
        found = self._skeleton(stream)
        return self._create(stream, *found) if found else None

    def _skeleton(self, stream: str) -> tuple[Skeleton, float] | None:
        if self.cfg.skeleton is not None:
            return self.cfg.skeleton, self.cfg.skeleton_fps
        stored = self.redis.hgetall(self.keys.skeleton(stream))
        if not stored:
            return None
        try:
            skeleton, fps, _ = parse_skeleton_message(
                [b"skeleton", json.dumps({"bvh": stored[b"bvh"].decode(),
                                          "fps": float(stored[b"fps"])}).encode()])
        except (ValueError, KeyError) as exc:
            self._reject("skeleton", exc)
            return None
        return skeleton, fps

    def restore_all(self) -> None:
        """(Re)start: every stream of this shard from its snapshot, then the log after it."""
        for raw in sorted(self.redis.smembers(self.keys.shard(self.shard))):
            stream = raw.decode("utf-8")
            snap, frames = self.redis.hmget(self.keys.snapshot(stream), "data", "frames")
            try:
                if snap:
                    pipeline = restore_pipeline(snap)
                else:
                    found = self._skeleton(stream)
                    if found is None:
                        continue
                    pipeline = self._new_pipeline(StreamSpec(stream, *found))
            except Exception as exc:  # a snapshot this version cannot read: start over
                self._reject("snapshot", exc)
                continue
            self._open(stream, pipeline).frames = int(frames or 0) if snap else 0
            self.counters["restored"] += 1
            self.catch_up(stream, None)

    def catch_up(self, stream: str, upto: int | None) -> None:
        """Push the logged frames after the stream's last one (and before seq `upto`)."""
        st = self.streams[stream]
        for frame in self._logged_after(stream, _last_seq(st.pipeline), upto):
            self.counters["replayed"] += 1
            self._push(stream, st, frame)
            st.replayed_to = frame.seq

    def _logged_after(self, stream: str, last: int | None, upto: int | None) -> list[Frame]:
        key = self.keys.log(stream)
        if upto is not None:  # the logger may be a moment behind this worker: wait briefly
            deadline = time.monotonic() + 0.5
            while time.monotonic() < deadline:
                newest = self.redis.xrevrange(key, count=1)
                if newest and int(newest[0][1][b"seq"]) >= upto - 1:
                    break
                time.sleep(0.005)
        out: list[Frame] = []
        high = "+"
        while True:
            batch = self.redis.xrevrange(key, max=high, count=_LOG_BATCH)
            done = not batch
            for entry_id, fields in batch:
                seq = int(fields[b"seq"])
                if last is not None and seq <= last:
                    done = True
                    break
                if upto is None or seq < upto:
                    try:
                        out.append(decode_frame_parts([b"frame", fields[b"h"], fields[b"p"]]))
                    except (ValueError, KeyError) as exc:
                        self._reject("log", exc)
                high = "(" + entry_id.decode()
            if done or len(batch) < _LOG_BATCH:
                break
        out.reverse()
        return out

    def _push(self, stream: str, st: _Stream, frame: Frame) -> None:
        events = self.table.step(st.live, frame.seq, st.pipeline.push, frame)
        events.extend(self.table.step(st.live, frame.seq, st.pipeline.idle))
        st.frames += 1
        self.counters["pushed"] += 1  # replays of frames a dead worker had pushed included
        self.emit(events)
        st.since_snapshot += 1
        if st.since_snapshot >= self.cfg.snapshot_every:
            self._snapshot(stream, st)

    def _snapshot(self, stream: str, st: _Stream) -> None:
        """Take the pipeline's state between two pushes; compress and store it on the
        sealing thread (in order), so the stream's next frames do not wait for zlib."""
        state = pickled(st.pipeline)
        last = _last_seq(st.pipeline)
        fields: dict[str, str | int] = {"seq": "" if last is None else str(last),
                                        "frames": st.frames}
        st.since_snapshot = 0

        def store() -> None:
            data = seal(state)
            self.redis.hset(self.keys.snapshot(stream), mapping={"data": data, **fields})
            self.counters["snapshots"] += 1
            self.counters["snapshot_bytes"] = len(data)

        self._sealer.submit(store)


    def emit(self, events: list[Event]) -> None:
        """Append events to the Redis sink unless their id is already there."""
        if not events:
            return
        args: list[str] = []
        for e in events:
            args += [e.id, event_json(e, compact=False)]
        self._emit(keys=[self.keys.events, self.keys.event_ids, self.keys.totals(self.shard)],
                   args=args)

    def retire_idle(self) -> None:
        """Flush and forget the streams that sent nothing for `stream_idle` seconds."""
        for live in self.table.expired(time.monotonic()):
            self.retire(live.name)

    def retire(self, stream: str) -> None:
        """End of a stream: the logged frames it missed, its final events, its Redis keys."""
        st = self.streams[stream]
        self.catch_up(stream, None)
        self.emit(self.table.step(st.live, None, st.pipeline.flush))
        self._sealer.wait()  # no snapshot of this stream written after its keys are deleted
        done = self.redis.pipeline(transaction=True)  # counted once, or restored and redone
        done.delete(self.keys.snapshot(stream), self.keys.log(stream), self.keys.skeleton(stream))
        done.srem(self.keys.shard(self.shard), stream)
        done.hincrby(self.keys.totals(self.shard), "frames", st.frames)
        done.execute()
        self.table.close(st.live)
        del self.streams[stream]
        self.retired.append(stream)


def _last_seq(pipeline: Pipeline) -> int | None:
    last = pipeline.guard.last
    return None if last is None else int(last.seq)
