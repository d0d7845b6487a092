#!/usr/bin/env bash
# Build the local base images without any image registry.
#
#   docker/build-base-image.sh            # build what is missing or stale, else say so and exit 0
#   FXSWARM_BASE_REBUILD=1 docker/build-base-image.sh   # build again
#
# Three layers, each built only when missing or stale:
#   1. fxswarm-rootfs:bookworm       a minimal Debian root (debootstrap --variant=minbase, with
#                                    python3 and python3-venv) from the configured Debian mirror,
#                                    imported with `docker import`.
#   2. fxswarm-base-core:bookworm    that root plus a virtualenv at /opt/venv holding the project's
#                                    core dependencies ([project] dependencies: numpy, msgpack, msgspec,
#                                    zenoh), the base of the agent, world, leader and router images.
#   3. fxswarm-base-logger:bookworm  the core base plus the `logger` extra (rerun-sdk, pyarrow):
#                                    the logger image's base. Built on the core base, so the two
#                                    share its layers on disk.
# Wheels are downloaded here, on the host (PyPI is the only index asked), and installed offline.
# Each base is labelled with a hash of its dependency list, so a change of dependencies rebuilds
# it and nothing else does. The bases keep the build backend's wheels (setuptools, wheel) in
# /opt/wheels and set PIP_NO_INDEX/PIP_FIND_LINKS, so the role Dockerfiles' `pip install .`
# works offline on top of them.
#
# Environment: DEBIAN_MIRROR (default: the first URI in /etc/apt/sources.list.d/debian.sources,
# else http://deb.debian.org/debian), DEBIAN_SUITE (bookworm), FXSWARM_BASE_CORE_IMAGE,
# FXSWARM_BASE_LOGGER_IMAGE (the names above), PYTHON (a Python with pip for the download,
# default the repo's .venv).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/.." && pwd)"
suite="${DEBIAN_SUITE:-bookworm}"
rootfs_image="${FXSWARM_ROOTFS_IMAGE:-fxswarm-rootfs:$suite}"
core_image="${FXSWARM_BASE_CORE_IMAGE:-fxswarm-base-core:$suite}"
logger_image="${FXSWARM_BASE_LOGGER_IMAGE:-fxswarm-base-logger:$suite}"
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

# One list of requirements from pyproject.toml (one place for them): core, logger or build.
requirements() {
    "$python" - "$repo/pyproject.toml" "$1" <<'EOF'
import sys, tomllib
with open(sys.argv[1], "rb") as f:
    project = tomllib.load(f)
which = sys.argv[2]
if which == "core":
    print("\n".join(project["project"]["dependencies"]))
elif which == "build":
    print("\n".join(project["build-system"]["requires"]))
else:
    print("\n".join(project["project"]["optional-dependencies"][which]))
EOF
}
core_deps="$(requirements core)"
logger_deps="$(requirements logger)"
build_deps="$(requirements build)"
core_hash="$(printf '%s\n%s\n%s\n' "$suite" "$core_deps" "$build_deps" | sha256sum | cut -c1-16)"
logger_hash="$(printf '%s\n%s\n' "$core_hash" "$logger_deps" | sha256sum | cut -c1-16)"

# Concurrent callers (parallel test sessions) wait for one another instead of racing.
exec 9>"/tmp/fxswarm-build-base-image.lock"
flock 9

up_to_date() {  # image hash
    [[ -z "${FXSWARM_BASE_REBUILD:-}" ]] &&
        [[ "$(docker image inspect -f "{{ index .Config.Labels \"$label\" }}" "$1" 2>/dev/null)" == "$2" ]]
}
if up_to_date "$core_image" "$core_hash" && up_to_date "$logger_image" "$logger_hash"; then
    say "$core_image ($core_hash) and $logger_image ($logger_hash) are up to date; nothing to do"
    exit 0
fi

work="$(mktemp -d /tmp/fxswarm-base.XXXXXX)"
builder="fxswarm-base-build-$$"
cleanup() { docker rm -f "$builder" >/dev/null 2>&1 || true; rm -rf "$work"; }
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

# Wheels for the image's Python (3.11) and glibc (bookworm: 2.36), whatever the host runs.
arch="$(uname -m)"
platforms=(--platform "linux_$arch" --platform "manylinux2014_$arch")
for minor in $(seq 17 36); do platforms+=(--platform "manylinux_2_${minor}_$arch"); done
download() {  # dest requirement...
    local dest="$1"; shift
    mkdir -p "$dest"
    "$python" -m pip download --quiet --disable-pip-version-check --only-binary=:all: \
        --python-version 3.11 --implementation cp "${platforms[@]}" --dest "$dest" "$@" ||
        die "pip download failed (is PyPI reachable?)"
}

# Installed by `docker run` + `docker commit` rather than `docker build`: the wheelhouse is
# mounted, never copied into a layer, and no intermediate image is left behind.
commit() {  # from-image to-image hash script
    local old_id
    old_id="$(docker image inspect -f '{{.Id}}' "$2" 2>/dev/null || true)"
    docker run --name "$builder" --network none -v "$work/wheels:/wheels:ro" "$1" sh -euc "$4" ||
        die "offline install into $2 failed"
    docker commit \
        --change "LABEL $label=$3" \
        --change 'ENV PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
        --change 'ENV VIRTUAL_ENV=/opt/venv' \
        --change 'ENV PIP_NO_INDEX=1' \
        --change 'ENV PIP_FIND_LINKS=/opt/wheels' \
        --change 'ENV PIP_DISABLE_PIP_VERSION_CHECK=1' \
        --change 'ENV PYTHONUNBUFFERED=1' \
        "$builder" "$2" >/dev/null
    docker rm "$builder" >/dev/null
    # The image this one replaces (stale dependencies) would linger untagged: remove it if unused.
    if [[ -n "$old_id" && "$old_id" != "$(docker image inspect -f '{{.Id}}' "$2")" ]]; then
        docker rmi "$old_id" >/dev/null 2>&1 || true
    fi
    say "built $2 (dependencies $3)"
}

# 2. The core base: what every role needs.
if ! up_to_date "$core_image" "$core_hash"; then
    say "downloading wheels for: $(echo $core_deps) (and to build: $(echo $build_deps))"
    mapfile -t dep_list <<<"$core_deps"
    mapfile -t build_dep_list <<<"$build_deps"
    download "$work/wheels/core" "${dep_list[@]}"
    download "$work/wheels/build" "${build_dep_list[@]}"
    say "installing them offline into $core_image"
    # pip stays in the venv (the role Dockerfiles install the project with it); its caches,
    # the tests and the headers that numpy ships do not.
    commit "$rootfs_image" "$core_image" "$core_hash" '
        python3 -m venv /opt/venv
        /opt/venv/bin/pip install --quiet --no-index --disable-pip-version-check /wheels/core/*.whl
        cp -r /wheels/build /opt/wheels
        site=$(/opt/venv/bin/python -c "import sysconfig; print(sysconfig.get_paths()[\"purelib\"])")
        rm -rf "$site"/numpy/*/tests "$site"/numpy/tests "$site"/numpy/_core/include "$site"/numpy/f2py
        find /opt/venv -name __pycache__ -type d -prune -exec rm -rf {} +
        rm -rf /root/.cache'
    docker image inspect "$logger_image" >/dev/null 2>&1 && docker rmi "$logger_image" >/dev/null 2>&1 || true
fi

# 3. The logger base: the core base plus Rerun.
if ! up_to_date "$logger_image" "$logger_hash"; then
    say "downloading wheels for: $(echo $logger_deps)"
    mapfile -t dep_list <<<"$logger_deps"
    download "$work/wheels/logger" "${dep_list[@]}"
    say "installing them offline into $logger_image"
    commit "$core_image" "$logger_image" "$logger_hash" '
        /opt/venv/bin/pip install --quiet --no-index --disable-pip-version-check \
            --find-links /wheels/logger /wheels/logger/*.whl
        find /opt/venv -name __pycache__ -type d -prune -exec rm -rf {} +
        rm -rf /root/.cache'
fi
