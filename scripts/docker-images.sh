#!/usr/bin/env bash
# The compose file's images built on a machine that reaches Debian's and Python's package
# registries but no registry of images (no `docker pull`), each cached by the content it is made
# from (a second run rebuilds nothing):
#   cmrt-base:bookworm         Debian bookworm minbase by debootstrap (for debian:bookworm-slim)
#   cmrt-redis:bookworm        Debian's redis-server          (for redis:7-bookworm)
#   cmrt-postgres:bookworm     Debian's postgresql (15)       (for postgres:16-bookworm)
#   cmrt-service:latest        the project's Dockerfile on cmrt-base, its Python packages from a
#                              wheelhouse built here on the host (.wheelhouse/)
# Use them with the compose file through its variables (what `make test-compose` sets):
#   CMRT_BASE_IMAGE=cmrt-base:bookworm CMRT_REDIS_IMAGE=cmrt-redis:bookworm \
#   CMRT_POSTGRES_IMAGE=cmrt-postgres:bookworm docker compose up -d
# Builds use the host's network (`--network host`) only for apt-get inside them; pip never runs
# against an index inside an image. Needs an engine (scripts/docker-engine.sh), debootstrap and
# the project's .venv (make setup). CMRT_IMAGES_REBUILD=1 ignores the cache.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
SUITE=bookworm
MIRROR=${CMRT_DEBIAN_MIRROR:-http://deb.debian.org/debian}
BASE=cmrt-base:$SUITE
REDIS=cmrt-redis:$SUITE
POSTGRES=cmrt-postgres:$SUITE
APP=${CMRT_IMAGE:-cmrt-service:latest}
LABEL=org.cmrt.content
T0=$(date +%s)

hash_of() {  # sha256 of the given files' contents and names, in a stable order
    find "$@" -type f ! -path '*/__pycache__/*' ! -name '*.pyc' -print0 | LC_ALL=C sort -z \
        | xargs -0 sha256sum | sha256sum | cut -c1-16
}
image_key() {  # the content key an image was built from ("" if there is no such image)
    docker image inspect -f "{{ index .Config.Labels \"$LABEL\" }}" "$1" 2>/dev/null || true
}
image_id() {
    docker image inspect -f '{{.Id}}' "$1"
}
fresh() {  # fresh IMAGE KEY: true if IMAGE exists, built from KEY
    [ "${CMRT_IMAGES_REBUILD:-0}" != 1 ] && [ "$(image_key "$1")" = "$2" ]
}
say() { echo "docker-images: $*"; }

# -- the base: a Debian root file system by debootstrap, imported -------------------------------
key=$(printf '%s\n' "debootstrap --variant=minbase $SUITE $MIRROR" \
      "$(hash_of scripts/docker-images.sh)" | sha256sum | cut -c1-16)
if fresh "$BASE" "$key"; then
    say "$BASE up to date"
else
    say "building $BASE (debootstrap --variant=minbase $SUITE)"
    root=$(mktemp -d /var/tmp/cmrt-rootfs.XXXXXX)
    trap 'rm -rf "$root"' EXIT
    debootstrap --variant=minbase "$SUITE" "$root" "$MIRROR" >"$root.log" 2>&1 \
        || { tail -20 "$root.log" >&2; exit 1; }
    rm -f "$root.log"
    # as the official slim image: no package lists or caches kept, no manuals
    rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/*.bin "$root"/usr/share/doc/* \
        "$root"/usr/share/man/*
    tar -C "$root" -c . | docker import \
        -c "LABEL $LABEL=$key" -c 'CMD ["bash"]' -c 'ENV LANG=C.UTF-8' - "$BASE" >/dev/null
    rm -rf "$root"
    trap - EXIT
fi
base_id=$(image_id "$BASE")

# -- Redis and PostgreSQL from Debian's packages ------------------------------------------------
build_service() {  # build_service IMAGE NAME: scripts/images/NAME.Dockerfile on the base
    local image=$1 name=$2 k
    k=$(printf '%s\n' "$base_id" "$(hash_of scripts/images/"$name".Dockerfile \
        scripts/images/"$name"-entrypoint.sh)" | sha256sum | cut -c1-16)
    if fresh "$image" "$k"; then
        say "$image up to date"
        return
    fi
    say "building $image"
    docker build -q --network host --build-arg BASE_IMAGE="$BASE" --label "$LABEL=$k" \
        -f scripts/images/"$name".Dockerfile -t "$image" scripts/images >/dev/null
}
build_service "$REDIS" redis
build_service "$POSTGRES" postgres

# -- the wheelhouse: the project's dependencies (and build backend) as wheels, built on the host --
# pinned to the versions installed in .venv, so that the image runs what the tests ran here
reqs=$("$PY" - <<'EOF'
import tomllib
p = tomllib.load(open("pyproject.toml", "rb"))
print("\n".join(p["build-system"]["requires"] + p["project"]["dependencies"]))
EOF
)
pins=$("$PY" -m pip freeze --exclude-editable --all 2>/dev/null | grep '==' || true)
wkey=$(printf '%s\n' "$reqs" "$pins" "$("$PY" -c 'import sys; print(sys.version_info[:2])')" \
       | sha256sum | cut -c1-16)
if [ -f .wheelhouse/.key ] && [ "$(cat .wheelhouse/.key)" = "$wkey" ] \
        && [ "${CMRT_IMAGES_REBUILD:-0}" != 1 ]; then
    say "wheelhouse up to date ($(ls .wheelhouse/*.whl | wc -l) wheels)"
else
    say "building the wheelhouse (.wheelhouse/)"
    rm -rf .wheelhouse && mkdir .wheelhouse
    printf '%s\n' "$reqs" > .wheelhouse/requirements.txt
    printf '%s\n' "$pins" > .wheelhouse/constraints.txt
    "$PY" -m pip wheel -q --wheel-dir .wheelhouse -r .wheelhouse/requirements.txt \
        -c .wheelhouse/constraints.txt
    rm .wheelhouse/requirements.txt .wheelhouse/constraints.txt
    echo "$wkey" > .wheelhouse/.key
fi

# -- the application image: the project's Dockerfile, as docker-compose.yml builds it -----------
akey=$(printf '%s\n' "$base_id" "$wkey" "$(hash_of Dockerfile .dockerignore pyproject.toml \
       README.md cmrt cli sim optim store worker service examples)" | sha256sum | cut -c1-16)
# (no label on it: `docker compose build` of the same Dockerfile and context then finds every
# layer in the cache and yields the same image; the key and image id are kept in .wheelhouse/)
state=.wheelhouse/.app-image
if [ "${CMRT_IMAGES_REBUILD:-0}" != 1 ] && [ -f "$state" ] \
        && [ "$(cat "$state")" = "$akey $(image_id "$APP" 2>/dev/null || true)" ]; then
    say "$APP up to date"
else
    say "building $APP"
    docker build -q --network host --build-arg BASE_IMAGE="$BASE" -t "$APP" . >/dev/null
    echo "$akey $(image_id "$APP")" > "$state"
fi

say "done in $(( $(date +%s) - T0 )) s:"
docker image ls --format '  {{.Repository}}:{{.Tag}}  {{.Size}}' \
    | grep -E "^  ($BASE|$REDIS|$POSTGRES|$APP) " || true
