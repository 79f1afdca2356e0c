"""The driver's frame logger of a cluster run: every valid frame appended to its stream's
Redis Stream (trimmed), so a restarted shard worker replays what it missed."""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from typing import Any

import zmq

from ..adapters.zmq import decode_frame_parts
from .live import ClusterConfig, _redis, parse_skeleton_message, split_topic, subscriptions
from .placement import Placement, RedisKeys

__all__ = ["FrameLogger"]


class FrameLogger:
    """The retained frame log: subscribes to every topic and appends each valid frame to its
    stream's Redis Stream, trimmed to the snapshot interval plus `failover_seconds` at the
    stream's rate; keeps each stream's skeleton and registers the stream with its shard.
    Runs in the driver process (it must outlive the workers it covers for)."""

    def __init__(self, config: ClusterConfig) -> None:
        self.cfg = config
        self.keys = RedisKeys(config.run)
        self.redis = _redis(config.redis_url)
        self.placement = Placement(self.redis, self.keys, config.shards)
        self.logged = 0
        self.rejects: Counter[str] = Counter()
        self.last_frame_at: float | None = None
        self.error: str | None = None  # why the logger stopped, if it failed
        self.subscribed = threading.Event()
        self._fps: dict[str, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="streamkey-frame-log",
                                        daemon=True)

    def retain(self, stream: str) -> int:
        """Frames kept in the stream's log."""
        fps = self._fps.get(stream, self.cfg.skeleton_fps)
        return self.cfg.snapshot_every + math.ceil(self.cfg.failover_seconds * fps)

    def start(self) -> None:
        """Place `--streams` ids (in their order), then start logging on a thread."""
        self.placement.place(self.cfg.streams or [])
        self._thread.start()
        self.subscribed.wait(10.0)

    def stop(self) -> None:
        """Stop logging."""
        self._stop.set()
        self._thread.join(10.0)

    def _serve(self) -> None:
        sock: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVHWM, 100_000)
        for prefix in subscriptions(self.cfg.streams):
            sock.setsockopt(zmq.SUBSCRIBE, prefix)
        sock.connect(self.cfg.endpoint)
        self.subscribed.set()
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                if not poller.poll(100):
                    continue
                pipe = self.redis.pipeline(transaction=False)
                for _ in range(512):
                    try:
                        parts = sock.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    self.log(parts, pipe)
                pipe.execute()
        except Exception as exc:  # Redis gone: the driver sees `error` and stops the run
            self.error = f"frame log: {type(exc).__name__}: {exc}"
        finally:
            sock.close(linger=0)

    def log(self, parts: list[bytes], pipe: Any) -> None:
        """Queue one message's Redis writes on `pipe`; never raises (rejects counted)."""
        try:
            stream, body = split_topic(parts)
            if body[0] == b"skeleton":
                _, fps, bvh = parse_skeleton_message(body)
                self._fps[stream] = fps
                pipe.hset(self.keys.skeleton(stream), mapping={"bvh": bvh, "fps": repr(fps)})
                pipe.sadd(self.keys.shard(self.placement.shard(stream)), stream)
                return
            if body[0] != b"frame":
                self.rejects["topic"] += 1
                return
            frame = decode_frame_parts(body)
        except (ValueError, TypeError, IndexError, RecursionError):
            self.rejects["malformed"] += 1
            return
        pipe.xadd(self.keys.log(stream), {"seq": frame.seq, "h": body[1], "p": body[2]},
                  maxlen=self.retain(stream), approximate=True)
        self.logged += 1
        self.last_frame_at = time.monotonic()
