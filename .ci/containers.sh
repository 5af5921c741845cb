#!/usr/bin/env bash
# CI: the cluster in containers (`make test-containers`) on an image built here.
#
# Starts dockerd where none answers (installing docker.io first where it is absent), makes
# the base from Debian's packages once (deploy/make-base.sh; the tag $BASE is kept for later
# runs), builds the image under a tag of this run's own, runs the tests, and removes what
# it made even when a step fails: the tests' containers and networks (by label), the image
# tag, the dockerd it started. dockerd sets the FORWARD chain's policy to DROP, which stops
# other bridges (the network-namespace test's) from forwarding: the policy found before
# dockerd started is put back as soon as dockerd answers, and again on exit. Every wait is
# bounded.
set -euo pipefail
cd "$(dirname "$0")/.."

BASE=${BASE:-graft-base:bookworm}
IMAGE=graft:ci-$$
LABEL=graft.ci=$$
DOCKER=${DOCKER:-docker}
dockerd_pid="" policy="" no_start=""

say() { echo "containers: $*" >&2; }

# The FORWARD chain's policy; nothing where iptables is absent (a fresh machine has none).
forward_policy() {
  command -v iptables > /dev/null || return 0
  iptables -S FORWARD 2> /dev/null | awk '$1 == "-P" { print $3 }' || true
}

put_back_forward_policy() {
  if [ -n "$policy" ] && [ "$(forward_policy)" != "$policy" ]; then
    iptables -P FORWARD "$policy"
  fi
}

# bounded SECONDS WHAT COMMAND...: runs COMMAND once a second until it succeeds.
bounded() {
  local limit=$1 what=$2
  shift 2
  for ((i = 0; i < limit; i++)); do
    if "$@" > /dev/null 2>&1; then return 0; fi
    sleep 1
  done
  say "$what: not within $limit s"
  return 1
}

clean_up() {
  local status=$?
  if timeout 30 "$DOCKER" info > /dev/null 2>&1; then
    local made
    made=$(timeout 30 "$DOCKER" ps -aq --filter "label=$LABEL" || true)
    [ -z "$made" ] || timeout 120 "$DOCKER" rm -f $made > /dev/null || true
    made=$(timeout 30 "$DOCKER" network ls -q --filter "label=$LABEL" || true)
    [ -z "$made" ] || timeout 60 "$DOCKER" network rm $made > /dev/null || true
    timeout 60 "$DOCKER" image rm "$IMAGE" > /dev/null 2>&1 || true
  fi
  if [ -n "$dockerd_pid" ]; then
    kill "$dockerd_pid" 2> /dev/null || true
    bounded 30 "dockerd stopping" sh -c "! kill -0 $dockerd_pid" || kill -9 "$dockerd_pid" || true
  fi
  [ -z "$no_start" ] || rm -f "$no_start"
  put_back_forward_policy
  exit "$status"
}
trap clean_up EXIT
trap 'say "stopped at line $LINENO (exit $?)"' ERR

if ! timeout 30 "$DOCKER" info > /dev/null 2>&1; then
  # What to put back: without iptables nothing has set a policy yet (the kernel's ACCEPT).
  policy=$(forward_policy)
  [ -n "$policy" ] || policy=ACCEPT
  if ! command -v dockerd > /dev/null; then
    say "installing docker.io"
    timeout 300 apt-get update -q > /dev/null
    # Its package would start a dockerd of its own (policy-rc.d 101: start no service).
    if [ ! -e /usr/sbin/policy-rc.d ]; then
      no_start=/usr/sbin/policy-rc.d
      printf '#!/bin/sh\nexit 101\n' > "$no_start" && chmod +x "$no_start"
    fi
    DEBIAN_FRONTEND=noninteractive timeout 600 apt-get install -y -q docker.io > /dev/null
    [ -z "$no_start" ] || rm -f "$no_start"
  fi
  dockerd_log=$(mktemp /tmp/graft-dockerd.XXXXXX)
  say "starting dockerd (its log: $dockerd_log)"
  dockerd > "$dockerd_log" 2>&1 &
  dockerd_pid=$!
  bounded 120 "dockerd answering" "$DOCKER" info || { tail -20 "$dockerd_log" >&2; exit 1; }
  put_back_forward_policy
fi

# `make image` needs BuildKit: a docker CLI with its buildx plugin, or Debian's 20.10 client.
if ! "$DOCKER" buildx version > /dev/null 2>&1 && [ -x /usr/bin/docker ]; then
  DOCKER=/usr/bin/docker
fi

if ! "$DOCKER" image inspect "$BASE" > /dev/null 2>&1; then
  if ! command -v debootstrap > /dev/null; then
    DEBIAN_FRONTEND=noninteractive timeout 600 apt-get install -y -q debootstrap > /dev/null
  fi
  say "making the base $BASE from Debian's packages (kept for later runs)"
  start=$SECONDS
  timeout 1200 deploy/make-base.sh "$BASE"
  say "base made in $((SECONDS - start)) s"
fi

start=$SECONDS
timeout 1800 make image IMAGE="$IMAGE" BASE="$BASE" DOCKER="$DOCKER"
size=$("$DOCKER" image inspect -f '{{.Size}}' "$IMAGE")
say "image $IMAGE built in $((SECONDS - start)) s: $((size / 1000000)) MB"

start=$SECONDS
timeout 2400 make test-containers IMAGE="$IMAGE" DOCKER="$DOCKER" CONTAINER_LABEL="$LABEL"
say "make test-containers: $((SECONDS - start)) s"
