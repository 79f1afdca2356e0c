"""Consume keyframe events from several `streamkey run --to zmq+tcp://...` publishers (a
primary and its standby, or a worker restored from a snapshot that replays its frames) and
keep each event once, by its idempotent id.

    python examples/zmq_dedupe_consumer.py tcp://127.0.0.1:5556 tcp://127.0.0.1:5557 \
        [--count N] [--duplicates M]

Events are two-part messages `[b"event", JSON]`; the id is the event's `id` (schema v2):
`stream/method/frame/params-digest` for keyframes. The ids seen are kept in a bounded
window (the newest 100,000), enough for any replay after a restore.
"""

from __future__ import annotations

import argparse
import json
from collections import OrderedDict

import zmq

from streamkey.adapters.sinks import event_id

WINDOW = 100_000


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("endpoints", nargs="*", default=["tcp://127.0.0.1:5556"])
    parser.add_argument("--count", type=int, default=0,
                        help="exit after N distinct keyframes (0: never)")
    parser.add_argument("--duplicates", type=int, default=0,
                        help="with --count: also wait for M skipped duplicates")
    args = parser.parse_args()
    sock: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SUBSCRIBE, b"event")
    for endpoint in args.endpoints:
        sock.connect(endpoint)
    print(f"subscribed to {', '.join(args.endpoints)}", flush=True)
    seen: OrderedDict[str, None] = OrderedDict()
    kept = skipped = 0
    try:
        while not (args.count and kept >= args.count and skipped >= args.duplicates):
            _, body = sock.recv_multipart()
            event = json.loads(body)
            key = event_id(event)
            if key is not None and key in seen:
                skipped += 1
                continue
            if key is not None:
                seen[key] = None
                if len(seen) > WINDOW:
                    seen.popitem(last=False)
            if event["type"] == "keyframe":
                kept += 1
                print(f"{key}: {event['method']} keyframe {event['frame']} at "
                      f"{event['time']:.3f} s", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
        print(f"duplicates skipped: {skipped}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
