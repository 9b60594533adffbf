#!/usr/bin/env bash
# A Docker engine for the compose suite on a Debian bookworm machine (idempotent):
#   - installs Debian's engine (docker.io), the compose command (docker-compose, v1; the v2
#     plugin `docker compose` is used instead wherever it is installed) and debootstrap (the
#     offline base image, scripts/docker-images.sh), if missing;
#   - starts dockerd if no engine answers `docker info` (machines without systemd: its log goes
#     to /var/log/cmrt-dockerd.log) and waits until it answers.
# While dockerd runs, the kernel's FORWARD policy is DROP (dockerd sets it); the local-process
# suite's worker host (a network namespace) does not route through FORWARD, so it is unaffected.
set -euo pipefail
SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo

need=()
command -v dockerd >/dev/null || need+=(docker.io)
if ! command -v docker-compose >/dev/null && ! docker compose version >/dev/null 2>&1; then
    need+=(docker-compose)
fi
command -v debootstrap >/dev/null || need+=(debootstrap)
if [ ${#need[@]} -gt 0 ]; then
    echo "docker-engine: installing ${need[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
        "${need[@]}" >/dev/null
fi

if docker info >/dev/null 2>&1; then
    exit 0
fi
echo "docker-engine: starting dockerd (log: /var/log/cmrt-dockerd.log)"
# setsid: the daemon outlives this script and the CI step that ran it. Without any descriptor
# this script inherited beyond 0-2: a daemon holding, say, a `flock` lock's descriptor would
# hold that lock for as long as it runs.
(
    for fd in /proc/$BASHPID/fd/*; do
        fd=${fd##*/}
        [ "$fd" -gt 2 ] && eval "exec $fd>&-"
    done
    exec $SUDO setsid dockerd >>/var/log/cmrt-dockerd.log 2>&1 < /dev/null
) &
for _ in $(seq 60); do
    docker info >/dev/null 2>&1 && exit 0
    sleep 1
done
echo "docker-engine: dockerd did not answer within 60 s; its log:" >&2
tail -30 /var/log/cmrt-dockerd.log >&2
exit 1
