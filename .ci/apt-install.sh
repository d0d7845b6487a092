#!/usr/bin/env bash
# `.ci/apt-install.sh WHO PACKAGE...`: install Debian packages for an optional test dependency.
# Exit 0 once installed; otherwise say why on stderr, as WHO (no apt-get, not root and no
# passwordless sudo, apt-get failed), and exit 1. All output goes to stderr: callers use stdout.
set -u
who="$1"; shift
if ! command -v apt-get >/dev/null; then
    echo "$who: no apt-get; install $* by hand" >&2
    exit 1
fi
SUDO=""
if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else
        echo "$who: not root and no passwordless sudo; not installing $*" >&2
        exit 1
    fi
fi
if $SUDO apt-get update -qq >&2 && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >&2; then
    exit 0
fi
echo "$who: apt-get install $* failed" >&2
exit 1
