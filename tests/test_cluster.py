"""Cluster mode: shard workers fed by ZeroMQ topics, the Redis frame log
and snapshots, de-duplicated events; restarts by Ray (worker SIGKILL, node loss)."""

from __future__ import annotations

import random
from collections import Counter

import cluster_helpers
import pytest
from cluster_helpers import (
    CLIPS,
    Clip,
    Publisher,
    RedisServer,
    play,
    redis_events,
    wait_for,
)

from streamkey.cluster.framelog import FrameLogger
from streamkey.cluster.live import (
    ClusterConfig,
    Placement,
    RedisKeys,
    ShardWorker,
    split_topic,
    stream_topic,
)
from streamkey.methods import ONLINE_METHODS

pytestmark = pytest.mark.cluster
redis_server, publisher = cluster_helpers.redis_server, cluster_helpers.publisher
METHODS = list(ONLINE_METHODS)


def _config(pub: Publisher, redis_server: RedisServer, run: str, shards: int = 2,
            **kw) -> ClusterConfig:
    return ClusterConfig(pub.endpoint, redis_server.url, shards, METHODS, {}, run=run,
                         **{"snapshot_every": 120, "stream_idle": 2.0, **kw})


def test_a_worker_that_dies_mid_stream_resumes_from_snapshot_and_log(redis_server, publisher):
    """No Ray: worker A takes the first 300 frames and dies without a word (thread stopped,
    nothing flushed); frames 300..500 arrive with no worker at all (only the logger has
    them); worker B starts, restores the snapshot, replays the log, takes the rest. The
    de-duplicated events equal the uninterrupted run's."""
    # no idle retirement between the workers: on a loaded machine seconds may pass there
    cfg = _config(publisher, redis_server, "solo", shards=1, stream_idle=600.0)
    clip = Clip(CLIPS[0], "solo-stream", publisher)
    logger = FrameLogger(cfg)
    logger.start()
    a = ShardWorker(cfg, 0)
    a.start()
    assert a.ready.wait(30)
    publisher.wait_subscribers(2)
    publisher.send(clip.stream, clip.skeleton)
    play(publisher, [clip], 0, 300, period=0.001)
    wait_for(lambda: a.status()["streams"].get(clip.stream, {}).get("last_seq") == 300,
             "worker A at frame 300")
    a._stop.set()  # dies: no flush, no goodbye
    a._thread.join(10)
    play(publisher, [clip], 300, 500, period=0.001)
    wait_for(lambda: logger.logged >= 500, "the logger to have every frame")
    b = ShardWorker(cfg, 0)
    b.start()
    assert b.ready.wait(30)
    assert b.starts == 2 and b.counters["restored"] == 1 and b.counters["replayed"] >= 200
    publisher.wait_subscribers(3)
    play(publisher, [clip], 500, None, period=0.001)
    wait_for(lambda: logger.logged >= len(clip.frames), "every frame logged")
    status = b.stop()
    logger.stop()
    assert status["retired"] == [clip.stream]
    got = {e["id"]: e for e in redis_events(redis_server.client(), "solo")}
    want = clip.reference(METHODS)
    diff = {k: (got[k], want[k]) for k in got if k in want and got[k] != want[k]}
    assert not diff, "\n".join(f"{a}\n{b}" for a, b in list(diff.values())[:3])
    assert got == want
    assert sum(e["type"] == "keyframe" for e in got.values()) > 20
    assert status["counters"]["snapshot_bytes"] <= 16_000_000
    # the run's counts span both workers: every frame once, every event once
    assert status["totals"] == {"frames": len(clip.frames), "events": len(want),
                                "duplicates_dropped": status["totals"]["duplicates_dropped"]}
    assert status["totals"]["duplicates_dropped"] > 0  # B replayed what A had sent
    assert status["counters"]["frames"] == len(clip.frames)


def test_holes_in_the_live_stream_are_filled_from_the_log(redis_server, publisher):
    """Frames the worker never saw (dropped before it, seen by the logger) are taken from the
    log when the next live frame shows the hole: same events, no gap event."""
    cfg = _config(publisher, redis_server, "holes", shards=1)
    clip = Clip(CLIPS[1], "holey", publisher)
    logger = FrameLogger(cfg)
    logger.start()
    worker = ShardWorker(cfg, 0)  # not started: messages are handed over by hand
    worker.restore_all()
    publisher.wait_subscribers(1)
    publisher.send(clip.stream, clip.skeleton)
    worker.handle(stream_topic(clip.stream, clip.skeleton))
    rng = random.Random(14)
    play(publisher, [clip], 0, None, period=0.0005)  # the logger gets everything
    wait_for(lambda: logger.logged >= len(clip.frames), "every frame logged")
    for i, parts in enumerate(clip.frames):
        if i < 5 or rng.random() > 0.1:  # the worker misses a tenth of them
            worker.handle(stream_topic(clip.stream, parts))
    worker.retire(clip.stream)
    logger.stop()
    assert worker.counters["holes"] > 20
    got = {e["id"]: e for e in redis_events(redis_server.client(), "holes")}
    assert got == clip.reference(METHODS)


def test_malformed_messages_are_counted_never_raised(redis_server, publisher):
    """The worker's input boundary: random and truncated multipart messages are rejected by
    kind, the stream goes on, no exception escapes."""
    cfg = _config(publisher, redis_server, "fuzz", shards=1)
    clip = Clip(CLIPS[1], "fuzzed", publisher)
    worker = ShardWorker(cfg, 0)
    worker.handle(stream_topic(clip.stream, clip.skeleton))
    logger = FrameLogger(cfg)  # the driver's input boundary: the same messages
    pipe = logger.redis.pipeline(transaction=False)
    rng = random.Random(7)
    sent_bad = 0
    for i, parts in enumerate(clip.frames[:200]):
        message = stream_topic(clip.stream, parts)  # [b"fuzzed/frame", header, data]
        worker.handle(message)
        logger.log(message, pipe)
        bad = list(message)
        k = rng.randrange(5)
        if k == 0:
            bad = bad[:rng.randrange(1, 3)]
        elif k == 1:
            bad[1] = bytes(rng.randrange(256) for _ in range(rng.randrange(40)))
        elif k == 2:
            bad[2] = bad[2][: rng.randrange(len(bad[2]))]
        elif k == 3:
            bad[0] = b"fuzzed/nonsense"
        else:
            bad[0] = bytes([0xff, 0xfe])
        before = sum(worker.rejects.values())
        worker.handle(bad)
        logger.log(bad, pipe)
        if bad == message:
            continue  # the mutation happened to leave it valid
        sent_bad += 1
        assert sum(worker.rejects.values()) == before + 1, (i, k)
    for parts in ([], [b""], [b"x" * 300 + b"/frame", b"", b""], [b"fuzzed/skeleton", b"{}"]):
        worker.handle(parts)
        logger.log(parts, pipe)
        sent_bad += 1
    pipe.execute()
    assert sum(worker.rejects.values()) == sent_bad
    assert sum(logger.rejects.values()) == sent_bad and logger.logged == 200
    assert redis_server.client().xlen("streamkey:fuzz:log:fuzzed") == 200
    assert worker.status()["streams"][clip.stream]["frames"] == 200
    with pytest.raises(ValueError):
        split_topic([b"only-a-topic"])


def test_a_keyframer_fault_in_a_shard_is_reported_and_the_windows_restart(redis_server,
                                                                          publisher):
    """The stream table's one fault policy, as in the engine: a keyframer that raises leaves
    a status "error" event in the event log, its windows restart, the stream goes on."""
    # no periodic snapshot: a pipeline with a patched method cannot be pickled
    cfg = _config(publisher, redis_server, "fault", shards=1, snapshot_every=100_000)
    clip = Clip(CLIPS[1], "faulty", publisher)
    worker = ShardWorker(cfg, 0)  # not started: messages are handed over by hand
    worker.handle(stream_topic(clip.stream, clip.skeleton))
    pipeline = worker.streams[clip.stream].pipeline
    real_push = pipeline.push
    failing_seq = None

    def push(frame):  # type: ignore[no-untyped-def]
        nonlocal failing_seq
        if failing_seq is None and pipeline.guard.last is not None and frame.seq >= 100:
            failing_seq = frame.seq
            raise RuntimeError("injected keyframer fault")
        return real_push(frame)

    pipeline.push = push  # type: ignore[method-assign]
    for parts in clip.frames:
        worker.handle(stream_topic(clip.stream, parts))
    worker.retire(clip.stream)
    events = list(redis_events(redis_server.client(), "fault"))
    errors = [e for e in events if e["type"] == "status" and e["status"] == "error"]
    assert len(errors) == 1 and errors[0]["detail"]["seq"] == failing_seq
    assert "injected keyframer fault" in errors[0]["detail"]["error"]
    assert any(e["type"] == "keyframe" and e["frame"] > failing_seq + 60 for e in events)
    status = worker.status()
    assert status["keyframer_errors"] == 1 and "injected" in status["keyframer_faults"][0]
    assert worker.rejects == {}  # a fault is not a rejected message


def test_stream_ids_are_placed_balanced_and_stably(redis_server):
    """`s00`..`s07` over 2 shards: 4 + 4 in the order first seen, whatever their hashes; an
    id keeps its shard in every process (a restarted worker, the logger)."""
    client = redis_server.client()
    first = Placement(client, RedisKeys("place"), 2)
    ids = [f"s{i:02d}" for i in range(8)]
    shards = first.place(ids)
    assert shards == [0, 1] * 4
    other = Placement(redis_server.client(), RedisKeys("place"), 2)  # another process
    assert [other.shard(s) for s in reversed(ids)] == shards[::-1]
    assert other.shard("late") == 0 and first.shard("later") == 1
    three = Placement(client, RedisKeys("place3"), 3)
    assert sorted(Counter(three.place([f"performer-{i}" for i in range(9)])).values()) == [
        3, 3, 3]


def test_the_shards_count_every_frame_and_event_across_a_worker_restart(redis_server,
                                                                        publisher):
    """Four streams `s00`..`s03` over 2 shards (2 + 2); worker 0 dies mid-stream without a
    word and a new one takes over: the shards' totals count every frame and every event
    once (the restarted shard's frames come from its snapshots, its replays and after)."""
    cfg = _config(publisher, redis_server, "counts", shards=2, stream_idle=60.0)
    clips = [Clip(CLIPS[i % 2], f"s{i:02d}", publisher) for i in range(4)]
    logger = FrameLogger(cfg)
    logger.start()
    workers = [ShardWorker(cfg, 0), ShardWorker(cfg, 1)]
    for w in workers:
        w.start()
        assert w.ready.wait(30)
    publisher.wait_subscribers(3)
    for c in clips:
        publisher.send(c.stream, c.skeleton)
    play(publisher, clips, 0, 300, period=0.001)
    wait_for(lambda: all(workers[0].status()["streams"].get(c.stream, {}).get("last_seq")
                         == 300 for c in clips[0::2]), "shard 0 at frame 300")
    assert sorted(workers[0].status()["streams"]) == ["s00", "s02"]
    workers[0]._stop.set()  # dies: no flush, no goodbye
    workers[0]._thread.join(10)
    workers[0] = ShardWorker(cfg, 0)
    workers[0].start()
    assert workers[0].ready.wait(60) and workers[0].starts == 2
    publisher.wait_subscribers(4)
    play(publisher, clips, 300, None, period=0.001)
    total = sum(len(c.frames) for c in clips)
    wait_for(lambda: logger.logged >= total, "every frame logged")
    wait_for(lambda: sum(w.status()["totals"]["frames"] for w in workers) >= total,
             "every frame pushed")
    shards = [w.stop() for w in workers]
    logger.stop()
    got = list(redis_events(redis_server.client(), "counts"))
    want = sum(len(c.reference(METHODS)) for c in clips)
    assert len(got) == len({e["id"] for e in got}) == want
    assert [sorted(s["retired"]) for s in shards] == [["s00", "s02"], ["s01", "s03"]]
    assert sum(s["counters"]["frames"] for s in shards) == total
    assert sum(s["counters"]["events"] for s in shards) == want
