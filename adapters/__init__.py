"""Sources and sinks: translate between the wire and `Frame` / event dicts, nothing else.

`make_source` and `make_sink` turn an address (`osc://`, `zmq+tcp://`, `zmq+ipc://`,
`ws://`, `jsonl:`, `-`; sources also `axis+tcp://`, `axis+udp://`, `vmc://`) into the adapter;
the transports import lazily.
"""

from __future__ import annotations

from streamkey.errors import UsageError
from streamkey.motion import Skeleton

from .base import Address, Sink, Source, parse_address

__all__ = ["make_source", "make_sink", "parse_address", "Address", "Sink", "Source"]


def make_source(address: Address, listen: str | None = None, skeleton: Skeleton | None = None,
                fps: float | None = None) -> Source:
    """A frame source for `address` (OSC listener, ZeroMQ SUB/PULL)."""
    if address.scheme == "osc":
        from .osc import OscSource

        return OscSource(address, listen, skeleton, fps)
    if address.scheme in ("zmq+tcp", "zmq+ipc"):
        from .zmq import ZmqSource

        return ZmqSource(address, listen, skeleton, fps)
    if address.scheme in ("axis+tcp", "axis+udp"):
        from .axis import AxisSource

        return AxisSource(address, listen, skeleton, fps)
    if address.scheme == "vmc":
        from .vmc import VmcSource

        return VmcSource(address, listen, skeleton, fps)
    if address.scheme == "-":
        from .jsonl_source import StdinSource, read_skeleton_line

        if skeleton is None:
            import sys

            skeleton, fps = read_skeleton_line(sys.stdin.buffer)
        return StdinSource(skeleton, fps or 120.0)
    raise UsageError(f"{address}: frames can come from osc://HOST:PORT, zmq+tcp://HOST:PORT, "
                     "zmq+ipc://PATH, - (JSON Lines on stdin), axis+tcp://HOST:PORT, "
                     "axis+udp://HOST:PORT, vmc://HOST:PORT or a .bvh/.amc file")


def make_sink(address: Address, listen: str | None = None) -> Sink:
    """An event sink for `address`."""
    if address.scheme in ("axis+tcp", "axis+udp", "vmc"):
        raise UsageError(f"{address}: {address.scheme}:// is a frame source (--from), not a sink")
    if address.scheme == "osc":
        from .osc import OscEventSink

        return OscEventSink(address, listen)
    if address.scheme in ("zmq+tcp", "zmq+ipc"):
        from .zmq import ZmqEventSink

        return ZmqEventSink(address, listen)
    if address.scheme == "ws":
        from .websocket import WebSocketSink

        return WebSocketSink(address, listen)
    from .sinks import JsonlSink, StdoutSink

    if address.scheme == "jsonl":
        return JsonlSink(address)
    return StdoutSink()
