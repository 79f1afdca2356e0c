"""Sinks that can de-duplicate do: the JSON Lines log on restart, and the
ZeroMQ consumer example, by the events' idempotent ids."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys

from cmu import DATA, ROOT
from live_helpers import MS, free_port, read_jsonl, streamkey

from streamkey.adapters import make_sink, parse_address
from streamkey.adapters.sinks import event_id
from streamkey.bvh import read_bvh
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import ONLINE_METHODS
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

CLIP = DATA / "07_01.bvh"


def test_a_restored_stream_replayed_into_its_log_leaves_every_event_there_once(tmp_path):
    motion = read_bvh(CLIP)
    frames = motion.frames()
    whole = Pipeline(make_keyframers(motion, list(ONLINE_METHODS)))
    expected = [e.to_dict() for e in whole.push_block(frames) + whole.flush()
                if isinstance(e, KeyframeEvent)]
    log = tmp_path / "session.jsonl"

    async def offer_all(sink, events):
        await sink.start()
        for e in events:
            sink.offer(e)
        await sink.close()
        return sink.stats

    first = Pipeline(make_keyframers(motion, list(ONLINE_METHODS)))
    before = first.push_block(frames[:150])
    snapshot = first.snapshot()  # taken at frame 150 ...
    lost = first.push_block(frames[150:220])  # ... the worker dies at 220, unflushed
    asyncio.run(offer_all(make_sink(parse_address(f"jsonl:{log}")), before + lost))
    restored = Pipeline.restore(snapshot)  # a new worker: snapshot + the frames since it
    again = restored.push_block(frames[150:]) + restored.flush()
    stats = asyncio.run(offer_all(make_sink(parse_address(f"jsonl:{log}")), again))
    logged = [e for e in read_jsonl(log) if e["type"] == "keyframe"]
    assert sorted(map(event_id, logged)) == sorted(map(event_id, expected))
    assert len({event_id(e) for e in logged}) == len(logged)
    assert stats.duplicates == len([e for e in lost if isinstance(e, KeyframeEvent)]) > 0


def test_a_rerun_appending_to_its_log_skips_what_is_there_and_says_so(tmp_path):
    log = tmp_path / "take.jsonl"
    for _ in range(2):
        result = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", str(CLIP),
                                 "--fast", "--method", "speed,simplify", "--to", f"jsonl:{log}"],
                                capture_output=True, text=True, timeout=120 * MS)
        assert result.returncode == 0, result.stderr
    events = read_jsonl(log)
    keys = [event_id(e) for e in events if e["type"] == "keyframe"]
    assert len(keys) == len(set(keys)) > 5
    ids = [event_id(e) for e in events]  # keyframes, and the take's segment events
    assert len(ids) == len(set(ids)) == len(keys) + 2
    assert f"duplicates skipped {len(ids)}" in result.stderr


def test_zmq_consumer_example_keeps_each_event_of_two_publishers_once():
    ports = [free_port(1), free_port(1)]
    consumer = subprocess.Popen([sys.executable, str(ROOT / "examples" / "zmq_dedupe_consumer.py"),
                                 *[f"tcp://127.0.0.1:{p}" for p in ports], "--count", "4",
                                 "--duplicates", "3"], stdout=subprocess.PIPE, text=True)
    runs = []
    try:
        assert consumer.stdout.readline().startswith("subscribed")
        runs = [streamkey("run", "--from", str(CLIP), "--method", "simplify", "--to",
                          f"zmq+tcp://127.0.0.1:{p}") for p in ports]  # paced: both publish
        out, _ = consumer.communicate(timeout=60 * MS)
    finally:
        for p in (consumer, *runs):
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
                p.communicate(timeout=60 * MS)
    kept = [line.split(":")[0] for line in out.splitlines() if "keyframe" in line]
    assert len(kept) == 4 and len(set(kept)) == 4
    assert all(k.startswith("default/simplify/") for k in kept)
    skipped = int(out.strip().splitlines()[-1].rsplit(" ", 1)[1])
    assert skipped >= 3
