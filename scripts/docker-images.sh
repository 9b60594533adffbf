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
drop() {  # drop OLD_ID IMAGE: the image IMAGE's new build replaced, unless it is the same one
    # or something still uses it
    [ -z "$1" ] || [ "$1" = "$(image_id "$2")" ] || docker image rm "$1" >/dev/null 2>&1 || true
}

# -- the base: a Debian root file system by debootstrap, imported -------------------------------
make_rootfs() {  # make_rootfs DIR: the base's files (its key is this function's text)
    local root=$1
    debootstrap --variant=minbase "$SUITE" "$root" "$MIRROR" >"$root.log" 2>&1 \
        || { tail -20 "$root.log" >&2; return 1; }
    rm -f "$root.log"
    # as the official slim image: no package lists, caches or downloaded packages kept, and
    # none kept by later apt-get runs; no manuals or translations installed
    cat > "$root"/etc/apt/apt.conf.d/docker-clean <<'CONF'
DPkg::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true"; };
APT::Update::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/archives/partial/*.deb /var/cache/apt/*.bin || true"; };
Dir::Cache::pkgcache "";
Dir::Cache::srcpkgcache "";
CONF
    echo 'Acquire::Languages "none";' > "$root"/etc/apt/apt.conf.d/docker-no-languages
    cat > "$root"/etc/dpkg/dpkg.cfg.d/docker-excludes <<'CONF'
path-exclude /usr/share/doc/*
path-include /usr/share/doc/*/copyright
path-exclude /usr/share/man/*
path-exclude /usr/share/info/*
path-exclude /usr/share/locale/*
CONF
    rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/*.bin \
        "$root"/var/cache/apt/archives/*.deb "$root"/usr/share/man/* "$root"/usr/share/info/* \
        "$root"/usr/share/locale/*
    find "$root"/usr/share/doc -type f ! -name copyright -delete
}
key=$(printf '%s\n' "$SUITE $MIRROR" "$(declare -f make_rootfs)" | sha256sum | cut -c1-16)
if fresh "$BASE" "$key"; then
    say "$BASE up to date"
else
    say "building $BASE (debootstrap --variant=minbase $SUITE)"
    old=$(image_id "$BASE" 2>/dev/null || true)
    root=$(mktemp -d /var/tmp/cmrt-rootfs.XXXXXX)
    trap 'rm -rf "$root" "$root.log"' EXIT
    make_rootfs "$root"
    tar -C "$root" -c . | docker import \
        -c "LABEL $LABEL=$key" -c 'CMD ["bash"]' -c 'ENV LANG=C.UTF-8' - "$BASE" >/dev/null
    rm -rf "$root"
    trap - EXIT
    drop "$old" "$BASE"
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
    old=$(image_id "$image" 2>/dev/null || true)
    docker build -q --network host --build-arg BASE_IMAGE="$BASE" --label "$LABEL=$k" \
        -f scripts/images/"$name".Dockerfile -t "$image" scripts/images >/dev/null
    drop "$old" "$image"
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
# (not the build backend: .venv's own setuptools is whatever its venv started with)
pins=$("$PY" -m pip freeze --exclude-editable 2>/dev/null | grep '==' || true)
wkey=$(printf '%s\n' "$reqs" "$pins" "$("$PY" -c 'import sys; print(sys.version_info[:2])')" \
       "$(hash_of scripts/images/wheelhouse_fill.py)" | sha256sum | cut -c1-16)
if [ -f .wheelhouse/.key ] && [ "$(cat .wheelhouse/.key)" = "$wkey" ] \
        && [ "${CMRT_IMAGES_REBUILD:-0}" != 1 ]; then
    say "wheelhouse up to date ($(ls .wheelhouse/*.whl | wc -l) wheels)"
else
    say "building the wheelhouse (.wheelhouse/)"
    rm -rf .wheelhouse && mkdir .wheelhouse
    printf '%s\n' "$reqs" > .wheelhouse/requirements.txt
    printf '%s\n' "$pins" > .wheelhouse/constraints.txt
    "$PY" -m pip wheel -q --wheel-dir .wheelhouse -r .wheelhouse/requirements.txt \
        -c .wheelhouse/constraints.txt 2>&1 | grep -v "^WARNING: Location" || true
    ls .wheelhouse/*.whl >/dev/null
    # pip resolved the environment markers for this machine's Python; the image runs Debian's
    # (e.g. redis needs async-timeout below 3.11.3): add what that one needs as well
    image_py=$(apt-cache show python3.11 2>/dev/null | sed -n 's/^Version: \([0-9.]*\).*/\1/p' \
               | head -1)
    "$PY" scripts/images/wheelhouse_fill.py .wheelhouse "${image_py:-3.11.2}" \
        .wheelhouse/constraints.txt
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
    old=$(image_id "$APP" 2>/dev/null || true)
    docker build -q --network host --build-arg BASE_IMAGE="$BASE" -t "$APP" . >/dev/null
    drop "$old" "$APP"
    echo "$akey $(image_id "$APP")" > "$state"
fi

say "done in $(( $(date +%s) - T0 )) s:"
docker image ls --format '{{.Repository}}:{{.Tag}} {{.Size}}' \
    | grep -E "^($BASE|$REDIS|$POSTGRES|$APP) " | sed 's/^/  /' || true
