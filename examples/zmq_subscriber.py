"""Print the keyframe events that `streamkey run --to zmq+tcp://127.0.0.1:5556` publishes.

    python examples/zmq_subscriber.py tcp://127.0.0.1:5556 [--count N]

Events are two-part messages `[b"event", JSON]`; the JSON is the event schema of the README.
"""

from __future__ import annotations

import argparse
import json

import zmq


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("endpoint", nargs="?", default="tcp://127.0.0.1:5556")
    parser.add_argument("--count", type=int, default=0, help="exit after N keyframes (0: never)")
    args = parser.parse_args()
    sock: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SUBSCRIBE, b"event")
    sock.connect(args.endpoint)
    print(f"subscribed to {args.endpoint}", flush=True)
    seen = 0
    try:
        while True:
            _, body = sock.recv_multipart()
            event = json.loads(body)
            if event["type"] != "keyframe":
                continue
            seen += 1
            print(f"{event['method']:>8} keyframe {event['frame']:6d} at {event['time']:8.3f} s "
                  f"(score {event['score']:.3g}, +{event['latency_frames']} frames)", flush=True)
            if args.count and seen >= args.count:
                return 0
    except KeyboardInterrupt:
        return 0
    finally:
        sock.close()


if __name__ == "__main__":
    raise SystemExit(main())
