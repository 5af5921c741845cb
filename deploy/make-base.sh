#!/usr/bin/env bash
# Makes a local base image for deploy/Dockerfile from Debian's packages, where no container
# registry answers (so python:3.11-slim cannot be pulled): Debian bookworm (minbase) with
# Python 3.11, pip and venv, imported into Docker as NAME (default graft-base:bookworm).
#
#   sudo deploy/make-base.sh [NAME]          # needs debootstrap and a running dockerd
#   make image BASE=graft-base:bookworm
#
# $MIRROR names the Debian mirror (default http://deb.debian.org/debian).
set -euo pipefail

NAME=${1:-graft-base:bookworm}
MIRROR=${MIRROR:-http://deb.debian.org/debian}

die() { echo "make-base.sh: $*" >&2; exit 2; }
command -v debootstrap >/dev/null || die "no debootstrap: apt-get install debootstrap"
docker info >/dev/null 2>&1 || die "docker does not answer: start dockerd"
[ "$(id -u)" = 0 ] || die "debootstrap needs root"

dir=$(mktemp -d /tmp/graft-base.XXXXXX)
trap 'rm -rf "$dir"' EXIT
debootstrap --variant=minbase \
    --include=python3.11,python3-pip,python3-venv,ca-certificates \
    bookworm "$dir" "$MIRROR" > "$dir.log" 2>&1 \
    || die "debootstrap failed (its log: $dir.log)"
rm -f "$dir.log"
# apt's lists and caches would only make the image bigger.
rm -rf "$dir"/var/lib/apt/lists/* "$dir"/var/cache/apt/archives/*.deb
tar -C "$dir" -c . | docker import --change 'CMD ["python3"]' - "$NAME" > /dev/null
echo "$NAME: Debian bookworm minbase with $(chroot "$dir" python3 --version)"
