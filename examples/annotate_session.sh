#!/usr/bin/env bash
# Annotate a capture session: keyposes from a live OSC stream go to a durable JSON Lines log
# (one event per line, flushed as it happens, fsynced at the end) and, at the same time, to a
# music/dance patch over OSC. Stop with Ctrl-C: the keyframers flush, the log is closed and a
# summary (frames, drops, gaps, events, latency) is printed.
#
#   examples/annotate_session.sh SKELETON.bvh [LOG.jsonl]
#
# The capture system (or `.venv/bin/streamkey replay take.bvh --to osc://127.0.0.1:9000` to
# rehearse) sends /streamkey/frame messages to 127.0.0.1:9000. Set IDLE_EXIT=SECONDS to end
# the session by itself once the stream has been silent that long. The streamkey command is
# $STREAMKEY if set, else the checkout's .venv/bin/streamkey, else the one on PATH.
set -euo pipefail
skeleton=${1:?usage: $0 SKELETON.bvh [LOG.jsonl]}
log=${2:-session-$(date +%Y%m%d-%H%M%S).jsonl}
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ -n "${STREAMKEY:-}" ]; then
  streamkey=$STREAMKEY
elif [ -x "$root/.venv/bin/streamkey" ]; then
  streamkey=$root/.venv/bin/streamkey
else
  streamkey=$(type -P streamkey) || {
    echo "error: streamkey not found: set STREAMKEY, or install it in $root/.venv" >&2; exit 2; }
fi
extra=()
[ -n "${IDLE_EXIT:-}" ] && extra+=(--idle-exit "$IDLE_EXIT")
exec "$streamkey" run --from "osc://127.0.0.1:${OSC_IN:-9000}" --skeleton "$skeleton" \
    --method all --stream "${STREAM:-take}" \
    --to "jsonl:$log" --to "osc://127.0.0.1:${OSC_OUT:-9001}" \
    --summary "${log%.jsonl}.summary.json" "${extra[@]}"
