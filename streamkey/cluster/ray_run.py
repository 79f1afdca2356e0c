"""`streamkey cluster run`: shard workers as named Ray actors; placement and restarts are
Ray's, frames never pass through Ray (see `live.py` for the data path).

The actors are owned by the driver (this process), not detached: the driver also runs the
frame logger that covers a worker's failover, so a run without its driver is not a run; when
the driver ends, Ray ends its actors. Each actor has `max_restarts=-1`: Ray restarts a killed
worker process, or re-creates the actor on another node when its node is lost, and the new
actor restores its streams from Redis in its constructor.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from typing import Any

import ray

from ..errors import StreamkeyError
from ..threads import single_thread_defaults
from .framelog import FrameLogger
from .live import ClusterConfig, RedisKeys, ShardWorker

__all__ = ["ClusterRun", "ShardActor"]

NAMESPACE = "streamkey"


@ray.remote
class ShardActor:
    """A `ShardWorker` in a Ray actor; a worker whose loop fails exits so Ray restarts it."""

    def __init__(self, config: ClusterConfig, shard: int) -> None:
        self.worker = ShardWorker(config, shard)
        self.worker.start()
        threading.Thread(target=self._watch, daemon=True).start()

    def _watch(self) -> None:
        assert self.worker._thread is not None
        self.worker._thread.join()
        if not self.worker._stop.is_set():
            os._exit(1)  # the loop died (Redis or socket gone): let Ray restart the actor

    def ready(self, timeout: float = 120.0) -> bool:
        """True once subscribed and restored."""
        return self.worker.ready.wait(timeout)

    def status(self) -> dict[str, Any]:
        """The worker's status plus where it runs."""
        out = self.worker.status()
        out.update(pid=os.getpid(), node=ray.get_runtime_context().get_node_id())
        return out

    def stop(self) -> dict[str, Any]:
        """Flush every stream and stop receiving."""
        out = self.worker.stop()
        out.update(pid=os.getpid(), node=ray.get_runtime_context().get_node_id())
        return out


class ClusterRun:
    """One cluster run: the frame logger here, `config.shards` named actors on Ray."""

    def __init__(self, config: ClusterConfig, address: str | None = None,
                 actor_cpus: float = 1.0) -> None:
        self.cfg = config
        self.address = address
        self.actor_cpus = actor_cpus
        self.logger = FrameLogger(config)
        self.actors: list[Any] = []
        self._started_ray = False

    def actor_name(self, shard: int) -> str:
        """The Ray name of a shard's actor (namespace `streamkey`)."""
        return f"{self.cfg.run}/shard-{shard}"

    def start(self, ready_timeout: float = 180.0) -> list[str]:
        """Connect to (or start) Ray, start logging frames and the actors; returns the
        ready lines once every actor has restored its streams and subscribed."""
        env = single_thread_defaults()
        if not ray.is_initialized():
            options: dict[str, Any] = {"address": self.address} if self.address else {
                "num_cpus": max(os.cpu_count() or 1, int(self.cfg.shards * self.actor_cpus)),
                "include_dashboard": False, "object_store_memory": 100 * 1024 * 1024}
            ray.init(**options, namespace=NAMESPACE, runtime_env={"env_vars": env},
                     logging_level=logging.WARNING, log_to_driver=False,
                     configure_logging=False)
            self._started_ray = True
        self.logger.start()
        actor_class: Any = ShardActor  # an ActorClass at run time; ray types it as the class
        self.actors = [
            actor_class.options(name=self.actor_name(i), namespace=NAMESPACE,
                                max_restarts=-1, max_task_retries=-1,
                                num_cpus=self.actor_cpus, scheduling_strategy="SPREAD"
                                ).remote(self.cfg, i)
            for i in range(self.cfg.shards)]
        try:
            ray.get([a.ready.remote() for a in self.actors], timeout=ready_timeout)
        except ray.exceptions.GetTimeoutError:
            self.stop()
            raise StreamkeyError(
                f"the {self.cfg.shards} shard actors were not all running after "
                f"{ready_timeout:g} s: the Ray cluster needs {self.cfg.shards} x "
                f"{self.actor_cpus:g} free CPUs (--actor-cpus)") from None
        return [f"logging frames of {self.cfg.endpoint} to {self.cfg.redis_url}",
                f"{self.cfg.shards} shard actor(s) ready on Ray "
                f"({'cluster ' + self.address if self.address else 'local'}), events to "
                f"Redis stream {RedisKeys(self.cfg.run).events}"]

    def status(self) -> list[dict[str, Any]]:
        """Every shard's status (waits for restarting actors)."""
        return list(ray.get([a.status.remote() for a in self.actors]))

    def idle_for(self) -> float | None:
        """Seconds since the last frame was logged (None before the first)."""
        last = self.logger.last_frame_at
        return None if last is None else time.monotonic() - last

    def stop(self) -> list[dict[str, Any]]:
        """Flush every stream, stop the actors and the logger; returns the shards' status."""
        try:
            out = list(ray.get([a.stop.remote() for a in self.actors]))
        finally:
            self.logger.stop()
            for a in self.actors:
                ray.kill(a, no_restart=True)
            if self._started_ray:
                ray.shutdown()
        return out
