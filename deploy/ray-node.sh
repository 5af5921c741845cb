#!/usr/bin/env bash
# Starts one node of a graft Ray cluster with Ray's token auth, or copies the token to a worker.
#
#   deploy/ray-node.sh head   --ip HEAD_IP [--port 6379] [--num-cpus N] [RAY START OPTIONS...]
#   deploy/ray-node.sh worker --head HEAD_IP:6379 --ip WORKER_IP [--num-cpus N] [--labels k=v] ...
#   deploy/ray-node.sh copy-token USER@HOST         # scp the token file, mode 600
#
# copy-token gives the token to a worker, or to a machine outside the cluster that runs
# `graft train --address ray://HEAD_IP:10001` (Ray Client, whose server the head starts).
#
# Ray 2.60 authenticates every node and driver with a shared token when RAY_AUTH_MODE=token.
# The token lives in a file (~/.ray/auth_token, or $RAY_AUTH_TOKEN_PATH), never on a command
# line: `head` creates it if missing, `copy-token` copies it to a worker, `worker` refuses to
# start without it. Options after the known ones go to `ray start` unchanged (e.g.
# --temp-dir, --resources '{"minecraft": 4}'). $RAY names the ray executable (default: ray).
set -euo pipefail

RAY=${RAY:-ray}
TOKEN_FILE=${RAY_AUTH_TOKEN_PATH:-$HOME/.ray/auth_token}
export RAY_AUTH_MODE=token
# The GCS keeps 10,000 task events, not Ray's 100,000: each actor call is one, and their
# history grew a run's GCS by 130-170 MiB an hour (graft/orchestration/ray_session.py).
export RAY_task_events_max_num_task_in_gcs=${RAY_task_events_max_num_task_in_gcs:-10000}
# A Ray Client (ray://) session's own server process gets 120 s to come up, not Ray's 30:
# on a loaded head it took longer, and the client failed with "Initialization failure".
export RAY_CLIENT_SERVER_CHECK_CHANNEL_TIMEOUT_S=${RAY_CLIENT_SERVER_CHECK_CHANNEL_TIMEOUT_S:-120}

die() { echo "ray-node.sh: $*" >&2; exit 2; }

role=${1:-}
[ -n "$role" ] || die "give a role: head, worker or copy-token (see the top of this file)"
shift

case "$role" in
  copy-token)
    target=${1:-}
    [ -n "$target" ] || die "copy-token needs USER@HOST (a worker, or a ray:// client machine)"
    [ -s "$TOKEN_FILE" ] || die "no token at $TOKEN_FILE: start the head first"
    ssh "$target" 'umask 077 && mkdir -p ~/.ray'
    scp -q -p "$TOKEN_FILE" "$target:.ray/auth_token"
    ssh "$target" 'chmod 600 ~/.ray/auth_token'
    echo "copied the Ray token to $target:~/.ray/auth_token"
    exit 0
    ;;
  head|worker) ;;
  *) die "unknown role '$role': head, worker or copy-token" ;;
esac

ip="" port=6379 head="" num_cpus="" extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --ip) ip=$2; shift 2 ;;
    --port) port=$2; shift 2 ;;
    --head) head=$2; shift 2 ;;
    --num-cpus) num_cpus=$2; shift 2 ;;
    *) extra+=("$1"); shift ;;
  esac
done
[ -n "$ip" ] || die "$role needs --ip, this node's address the other nodes reach"
cpus=()
[ -z "$num_cpus" ] || cpus=(--num-cpus "$num_cpus")

if [ "$role" = head ]; then
  if [ ! -s "$TOKEN_FILE" ]; then
    mkdir -p "$(dirname "$TOKEN_FILE")"
    (umask 077 && python3 -c 'import secrets; print(secrets.token_hex(32), end="")' > "$TOKEN_FILE")
    echo "created a Ray token in $TOKEN_FILE; copy it to every worker (copy-token)"
  fi
  exec "$RAY" start --head --node-ip-address "$ip" --port "$port" "${cpus[@]}" \
    --include-dashboard false --disable-usage-stats "${extra[@]}"
fi

[ -n "$head" ] || die "worker needs --head HEAD_IP:PORT"
[ -s "$TOKEN_FILE" ] || die "no token at $TOKEN_FILE: copy the head's (copy-token) first"
exec "$RAY" start --address "$head" --node-ip-address "$ip" "${cpus[@]}" \
  --disable-usage-stats "${extra[@]}"
