#!/usr/bin/env bash
# Mesa's software Vulkan (lavapipe), so the Rerun viewer can render headless:
# `fxswarm report DIR --snapshot` and its test (which skips, saying why, without it).
# Idempotent; never fails the build: without root or apt it says so and returns.
set -u
if [ -f /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ] && ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
    exit 0
fi
if ! command -v apt-get >/dev/null; then
    echo "install-snapshot-deps: no apt-get; install Mesa's Vulkan drivers by hand for --snapshot" >&2
    exit 0
fi
SUDO=""
if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else
        echo "install-snapshot-deps: not root; skipping (snapshot tests will skip)" >&2
        exit 0
    fi
fi
$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 \
    || echo "install-snapshot-deps: apt-get failed; snapshot tests will skip" >&2
exit 0
