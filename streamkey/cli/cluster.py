"""`streamkey cluster run`: many live streams on Ray shard actors (`streamkey.cluster`): start a
`ClusterRun`, wait, stop, summarise."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from collections import Counter
from pathlib import Path
from typing import Any

from ..cluster import require
from ..errors import UsageError
from .options import add_roles_option, online_params, roles_of

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    """The `cluster run` subcommand."""
    p = sub.add_parser("cluster", help="live keyframes of many streams on a Ray cluster")
    runs = p.add_subparsers(dest="cluster_command", required=True, metavar="COMMAND")
    r = runs.add_parser("run", help="shard actors on Ray: ZeroMQ in, Redis log/snapshots, "
                        "de-duplicated events to a Redis stream")
    r.add_argument("--from", dest="source", required=True, metavar="zmq+tcp://HOST:PORT",
                   help="the frame publisher (topic = stream id)")
    r.add_argument("--shards", type=int, default=2, help="shard actors (default: 2)")
    r.add_argument("--redis", required=True, metavar="redis://HOST:PORT",
                   help="Redis for the frame log, snapshots and the event stream")
    r.add_argument("--address", help="an existing Ray cluster (default: a new local one)")
    r.add_argument("--run", default="default", help="name of this run: Redis key prefix "
                   "streamkey:RUN:* and actor names RUN/shard-I (default: default)")
    r.add_argument("--snapshot-every", type=int, default=600, metavar="FRAMES",
                   help="snapshot each stream every FRAMES frames (default: 600)")
    r.add_argument("--failover-seconds", type=float, default=30.0, metavar="SECONDS",
                   help="the frame log also covers this long an outage (default: 30)")
    r.add_argument("--stream-idle", type=float, default=10.0, metavar="SECONDS",
                   help="flush and retire a stream silent this long (default: 10)")
    r.add_argument("--streams", help="comma list of stream ids: subscribe to these topics "
                   "only (default: every topic, each shard keeping its own)")
    r.add_argument("--actor-cpus", type=float, default=1.0,
                   help="CPUs Ray reserves per shard actor (default: 1)")
    r.add_argument("--idle-exit", type=float, metavar="SECONDS",
                   help="stop once frames have flowed and then none came for SECONDS")
    r.add_argument("--summary", help="also write the shards' status as JSON to this file")
    r.add_argument("--skeleton", help="BVH/AMC file: one skeleton for every stream (else "
                   "each stream's skeleton message)")
    r.add_argument("--method", default="all", help="online methods, a list, or all")
    r.add_argument("--lookahead", type=int, help="lookahead in frames (default: method's)")
    add_roles_option(r)
    r.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run until Ctrl-C / SIGTERM (or `--idle-exit`), then flush every stream."""
    from ..adapters import parse_address
    from ..methods import parse_methods
    from ..streaming import check_online_params

    params, roles = online_params(args), roles_of(args)

    require("ray", "cluster run")
    require("redis", "cluster run")
    source = parse_address(args.source)
    if source.scheme not in ("zmq+tcp", "zmq+ipc"):
        raise UsageError(f"--from {args.source}: cluster run takes zmq+tcp://HOST:PORT")
    if not args.redis.startswith(("redis://", "rediss://", "unix://")):
        raise UsageError(f"--redis {args.redis}: expected redis://HOST:PORT")
    for name, value in (("--shards", args.shards), ("--snapshot-every", args.snapshot_every)):
        if value < 1:
            raise UsageError(f"{name} must be at least 1, got {value}")
    methods = parse_methods(args.method, online=True)
    check_online_params(methods, params)
    from ..cluster.live import ClusterConfig

    config = ClusterConfig(source.zmq_endpoint, args.redis, args.shards, methods, params,
                           args.lookahead, args.run, args.snapshot_every,
                           args.failover_seconds, args.stream_idle,
                           [s for s in args.streams.split(",") if s] if args.streams else None)
    if args.skeleton:
        from ..amc import bvh_equivalent, read_motion

        motion = bvh_equivalent(read_motion(args.skeleton))
        motion.skeleton.roles = roles or motion.skeleton.roles
        config.skeleton, config.skeleton_fps = motion.skeleton, motion.fps
    _check_redis(args.redis)
    from ..cluster.live import new_notices
    from ..cluster.ray_run import ClusterRun

    run = ClusterRun(config, args.address, args.actor_cpus)
    stop = threading.Event()
    said = 0  # refused input, explained by the shards: printed as they come
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        for line in run.start():
            print(line, file=sys.stderr, flush=True)
        while not stop.wait(0.2):
            if run.logger.error:
                break
            for line in new_notices(run.logger.redis, config.run, said):
                said += 1
                print(f"warning: {line}", file=sys.stderr, flush=True)
            idle = run.idle_for()
            if args.idle_exit is not None and idle is not None and idle >= args.idle_exit:
                break
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        shards = run.stop()
    total = {k: sum(s["counters"].get(k, 0) for s in shards)
             for k in ("frames", "replayed", "events", "duplicates_dropped", "snapshots")}
    restarts = sum(s["starts"] - 1 for s in shards)
    print(f"cluster: {len(shards)} shard(s), {total['frames']} frames "
          f"({total['replayed']} replayed from the log), {total['events']} events "
          f"({total['duplicates_dropped']} duplicates dropped), {total['snapshots']} snapshots, "
          f"{restarts} actor restart(s), {run.logger.logged} frames logged", file=sys.stderr)
    problems: Counter[str] = Counter()
    for shard in shards:
        problems.update(shard.get("input_problems", {}))
    if problems:
        print("input problems: " + ", ".join(f"{k} {v}" for k, v in sorted(problems.items())),
              file=sys.stderr)
    if run.logger.error:  # without the log a worker's restart would lose frames: fail
        print(f"error: {run.logger.error}", file=sys.stderr)
        return 2
    if args.summary:
        Path(args.summary).write_text(json.dumps({"shards": shards, "total": total,
                                                  "logged": run.logger.logged}, indent=1) + "\n")
    return 0


def _check_redis(url: str) -> None:
    """Refuse clearly, before Ray starts, when Redis is not there."""
    import redis

    try:
        redis.Redis.from_url(url, socket_connect_timeout=5).ping()
    except redis.RedisError as exc:
        raise UsageError(f"--redis {url}: {exc}") from None
