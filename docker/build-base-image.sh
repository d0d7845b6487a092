#!/usr/bin/env bash
# Build the local base image fxswarm-base:bookworm without any image registry.
#
#   docker/build-base-image.sh            # build if missing or stale, else say so and exit 0
#   FXSWARM_BASE_REBUILD=1 docker/build-base-image.sh   # build again
#
# Two layers, each built only when missing:
#   1. fxswarm-rootfs:bookworm  a minimal Debian root (debootstrap --variant=minbase, with
#                               python3 and python3-venv) from the configured Debian mirror,
#                               imported with `docker import`.
#   2. fxswarm-base:bookworm    that root plus a virtualenv at /opt/venv holding the project's
#                               runtime dependencies, installed offline from a wheelhouse that
#                               pip downloaded on the host (PyPI is the only index it asks).
#                               Labelled with a hash of pyproject.toml's dependency list, so a
#                               change of dependencies rebuilds it and nothing else does.
# The image keeps the build backend's wheels (setuptools, wheel) in /opt/wheels and sets PIP_NO_INDEX/PIP_FIND_LINKS,
# so `pip install .` of the project (the Dockerfile) works offline on top of it.
#
# Environment: DEBIAN_MIRROR (default: the first URI in /etc/apt/sources.list.d/debian.sources,
# else http://deb.debian.org/debian), DEBIAN_SUITE (bookworm), FXSWARM_BASE_IMAGE
# (fxswarm-base:bookworm), PYTHON (a Python with pip for the download, default the repo's .venv).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/.." && pwd)"
suite="${DEBIAN_SUITE:-bookworm}"
rootfs_image="${FXSWARM_ROOTFS_IMAGE:-fxswarm-rootfs:$suite}"
base_image="${FXSWARM_BASE_IMAGE:-fxswarm-base:$suite}"
label="org.fxswarm.deps"

say() { echo "build-base-image: $*" >&2; }
die() { say "error: $*"; exit 1; }

command -v docker >/dev/null || die "no docker client on PATH"
docker info >/dev/null 2>&1 || die "no Docker engine answers (is dockerd running, may this user use it?)"

python="${PYTHON:-}"
if [[ -z "$python" ]]; then
    if [[ -x "$repo/.venv/bin/python" ]]; then python="$repo/.venv/bin/python"; else python=python3; fi
fi
"$python" -m pip --version >/dev/null 2>&1 || die "$python has no pip (set PYTHON to a Python with pip)"

# The runtime dependencies, one per line, straight from pyproject.toml (one place for them).
deps="$("$python" - "$repo/pyproject.toml" <<'EOF'
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    print("\n".join(tomllib.load(f)["project"]["dependencies"]))
EOF
)"
# ... and what building the project's own wheel needs (its build-system requirements).
build_deps="$("$python" - "$repo/pyproject.toml" <<'EOF'
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    print("\n".join(tomllib.load(f)["build-system"]["requires"]))
EOF
)"
deps_hash="$(printf '%s\n%s\n%s\n' "$suite" "$deps" "$build_deps" | sha256sum | cut -c1-16)"

# Concurrent callers (parallel test sessions) wait for one another instead of racing.
exec 9>"/tmp/fxswarm-build-base-image.lock"
flock 9

if [[ -z "${FXSWARM_BASE_REBUILD:-}" ]] &&
   [[ "$(docker image inspect -f "{{ index .Config.Labels \"$label\" }}" "$base_image" 2>/dev/null)" == "$deps_hash" ]]; then
    say "$base_image is up to date (dependencies $deps_hash); nothing to do"
    exit 0
fi

old_id="$(docker image inspect -f '{{.Id}}' "$base_image" 2>/dev/null || true)"
work="$(mktemp -d /tmp/fxswarm-base.XXXXXX)"
cleanup() { rm -rf "$work"; }
trap cleanup EXIT

# 1. The Debian root, imported as an image.
if [[ -n "${FXSWARM_BASE_REBUILD:-}" ]] || ! docker image inspect "$rootfs_image" >/dev/null 2>&1; then
    if ! command -v debootstrap >/dev/null; then
        [[ $EUID -eq 0 ]] || die "debootstrap is missing: apt-get install debootstrap (as root)"
        say "installing debootstrap"
        apt-get install -y -qq debootstrap >/dev/null 2>&1 ||
            { apt-get update -qq && apt-get install -y -qq debootstrap >/dev/null; }
    fi
    [[ $EUID -eq 0 ]] || die "debootstrap needs root"
    mirror="${DEBIAN_MIRROR:-}"
    if [[ -z "$mirror" && -r /etc/apt/sources.list.d/debian.sources ]]; then
        mirror="$(awk '/^URIs:/ {print $2; exit}' /etc/apt/sources.list.d/debian.sources)"
    fi
    mirror="${mirror:-http://deb.debian.org/debian}"
    say "debootstrap $suite from $mirror (a few minutes)"
    root="$work/root"
    debootstrap --variant=minbase --include=python3,python3-venv \
        "$suite" "$root" "$mirror" >"$work/debootstrap.log" 2>&1 ||
        { tail -n 30 "$work/debootstrap.log" >&2; die "debootstrap failed (log above)"; }
    # What a container never needs: package caches, docs, manuals.
    rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/* \
        "$root"/usr/share/doc/* "$root"/usr/share/man/* "$root"/usr/share/locale/*
    say "docker import -> $rootfs_image"
    tar -C "$root" --numeric-owner -c . |
        docker import \
            --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
            --change 'ENV LANG=C.UTF-8' \
            --change 'CMD ["/bin/bash"]' \
            - "$rootfs_image" >/dev/null
    rm -rf "$root"
fi

# 2. The wheelhouse (downloaded here, on the host), installed offline into the base image.
say "downloading wheels for: $(echo $deps) (and to build: $(echo $build_deps))"
mkdir -p "$work/wheels/run" "$work/wheels/build"
mapfile -t dep_list <<<"$deps"
mapfile -t build_dep_list <<<"$build_deps"
# Wheels for the image's Python (3.11) and glibc (bookworm: 2.36), whatever the host runs.
arch="$(uname -m)"
platforms=(--platform "linux_$arch" --platform "manylinux2014_$arch")
for minor in $(seq 17 36); do platforms+=(--platform "manylinux_2_${minor}_$arch"); done
download() {
    "$python" -m pip download --quiet --disable-pip-version-check --only-binary=:all: \
        --python-version 3.11 --implementation cp "${platforms[@]}" "$@" ||
        die "pip download failed (is PyPI reachable?)"
}
download --dest "$work/wheels/run" "${dep_list[@]}"
download --dest "$work/wheels/build" "${build_dep_list[@]}"

# Installed by `docker run` + `docker commit` rather than `docker build`: the wheelhouse is
# mounted, never copied into a layer, and no intermediate image is left behind.
say "installing them offline into $base_image"
builder="fxswarm-base-build-$$"
trap 'docker rm -f "$builder" >/dev/null 2>&1 || true; cleanup' EXIT
docker run --name "$builder" --network none -v "$work/wheels:/wheels:ro" "$rootfs_image" sh -euc '
    python3 -m venv /opt/venv
    /opt/venv/bin/pip install --quiet --no-index --disable-pip-version-check /wheels/run/*.whl
    cp -r /wheels/build /opt/wheels
    rm -rf /root/.cache' || die "offline install into the base image failed"
# The project'"'"'s own `pip install .` (the top-level Dockerfile) then needs no index: its
# build backend comes from /opt/wheels, its dependencies are already installed.
docker commit \
    --change "LABEL $label=$deps_hash" \
    --change 'ENV PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV VIRTUAL_ENV=/opt/venv' \
    --change 'ENV PIP_NO_INDEX=1' \
    --change 'ENV PIP_FIND_LINKS=/opt/wheels' \
    --change 'ENV PIP_DISABLE_PIP_VERSION_CHECK=1' \
    --change 'ENV PYTHONUNBUFFERED=1' \
    "$builder" "$base_image" >/dev/null
# The image this one replaces (stale dependencies) would linger untagged: remove it if unused.
if [[ -n "$old_id" && "$old_id" != "$(docker image inspect -f '{{.Id}}' "$base_image")" ]]; then
    docker rmi "$old_id" >/dev/null 2>&1 || true
fi
say "built $base_image (dependencies $deps_hash)"
