"""Cluster mode on Ray (acceptance): a loopback `ray.cluster_utils.Cluster`
(a head without CPUs and three one-CPU raylets), a real redis-server, a ZeroMQ publisher of
two streams. Worker SIGKILL and node loss mid-stream: the de-duplicated events equal an
uninterrupted run's, for every stream. The CLI runs as its own process against the same
cluster (`--address`)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import cluster_helpers
import pytest
import ray
from cluster_helpers import (
    CLIPS,
    Clip,
    Publisher,
    RedisServer,
    play_in_background,
    redis_events,
    stream_names,
    wait_for,
)
from live_helpers import MS, wait_ready
from ray.cluster_utils import Cluster  # the cluster extra: CI installs it, never skipped

from streamkey.cluster.live import ClusterConfig
from streamkey.cluster.ray_run import ClusterRun
from streamkey.methods import ONLINE_METHODS

pytestmark = pytest.mark.cluster
redis_server, publisher = cluster_helpers.redis_server, cluster_helpers.publisher
METHODS = list(ONLINE_METHODS)
NODE = {"num_cpus": 1, "object_store_memory": 80 * 1024 * 1024}


@pytest.fixture(scope="module")
def cluster():
    c = Cluster(initialize_head=True, head_node_args={
        **NODE, "num_cpus": 0, "include_dashboard": False})
    nodes = [c.add_node(**NODE) for _ in range(3)]
    c.wait_for_nodes(60)
    ray.init(address=c.address, include_dashboard=False, log_to_driver=False,
             logging_level="WARNING")
    yield c, nodes
    ray.shutdown()
    c.shutdown()


def _clips(pub: Publisher) -> list[Clip]:
    return [Clip(clip, name, pub) for clip, name in zip(CLIPS, stream_names(2), strict=True)]


def _check_events(redis_server: RedisServer, run: str, clips: list[Clip]) -> dict[str, dict]:
    got = {e["id"]: e for e in redis_events(redis_server.client(), run)}
    for clip in clips:
        mine = {k: v for k, v in got.items() if v["stream"] == clip.stream}
        want = clip.reference(METHODS)
        assert mine == want, f"{clip.stream}: {len(mine)} events, {len(want)} expected"
        assert sum(e["type"] == "keyframe" for e in mine.values()) > 20
    assert len(got) == sum(len(c.reference(METHODS)) for c in clips)
    return got


def _fault_run(cluster, redis_server, publisher, run: str, fault) -> list[dict]:
    """Two streams (one per shard); `fault(run, status of the victim shard 0)` once shard
    0 has taken 250 frames; returns the shards' final status."""
    cfg = ClusterConfig(publisher.endpoint, redis_server.url, 2, METHODS, {}, run=run,
                        snapshot_every=120, stream_idle=2.0)
    clips = _clips(publisher)
    job = ClusterRun(cfg)
    job.start()
    try:
        publisher.wait_subscribers(3)  # the frame logger and two shard actors
        player = play_in_background(publisher, clips)
        victim = wait_for(lambda: (s := job.status()[0])["streams"].get(
            clips[0].stream, {}).get("frames", 0) >= 250 and s, "shard 0 at 250 frames")
        fault(victim)
        player.join(120 * MS)
        wait_for(lambda: all(c.stream in sum((s["retired"] for s in job.status()), [])
                             for c in clips), "both streams flushed and retired", every=0.5)
    finally:
        status = job.stop()
    _check_events(redis_server, run, clips)
    return status


def test_worker_sigkill_mid_stream_gives_the_uninterrupted_events(cluster, redis_server,
                                                                 publisher):
    status = _fault_run(cluster, redis_server, publisher, "sigkill",
                        lambda victim: os.kill(victim["pid"], signal.SIGKILL))
    assert status[0]["starts"] == 2 and status[1]["starts"] == 1
    assert status[0]["counters"]["replayed"] > 0
    # the summary counts every frame and event across the restart
    clips = _clips(publisher)
    events = list(redis_events(redis_server.client(), "sigkill"))
    assert sum(s["counters"]["frames"] for s in status) == sum(len(c.frames) for c in clips)
    assert sum(s["counters"]["events"] for s in status) == len(events)


def test_node_loss_mid_stream_gives_the_uninterrupted_events(cluster, redis_server,
                                                            publisher):
    c, nodes = cluster
    lost: list[str] = []

    def lose_node(victim: dict) -> None:
        node = next(n for n in nodes if n.node_id == victim["node"])
        lost.append(node.node_id)
        c.remove_node(node)

    status = _fault_run(cluster, redis_server, publisher, "nodeloss", lose_node)
    assert status[0]["starts"] == 2 and status[0]["node"] != lost[0]
    assert status[0]["counters"]["replayed"] > 0


def test_cluster_run_cli_on_an_existing_ray_cluster(cluster, redis_server, publisher,
                                                    tmp_path):
    summary = tmp_path / "summary.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "streamkey", "cluster", "run", "--from", publisher.address,
         "--shards", "2", "--redis", redis_server.url, "--address", cluster[0].address,
         "--run", "cli", "--snapshot-every", "240", "--stream-idle", "1",
         "--idle-exit", "3", "--summary", str(summary)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_ready(proc, "shard actor(s) ready", timeout=120)
        publisher.wait_subscribers(3)
        clips = _clips(publisher)
        play_in_background(publisher, clips).join(120 * MS)
        out, err = proc.communicate(timeout=120 * MS)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    _check_events(redis_server, "cli", clips)
    shards = json.loads(summary.read_text())["shards"]
    assert sorted(sum((s["retired"] for s in shards), [])) == sorted(c.stream for c in clips)
