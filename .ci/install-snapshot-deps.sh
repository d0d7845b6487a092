#!/usr/bin/env bash
# Mesa's software Vulkan (lavapipe), so the Rerun viewer can render headless:
# `fxswarm report DIR --snapshot` and its test (which skips, saying why, without it).
# Idempotent; never fails the build: where it cannot install, it says so and returns.
set -u
if [ -f /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ] && ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
    exit 0
fi
"$(dirname "$0")/apt-install.sh" install-snapshot-deps mesa-vulkan-drivers libvulkan1 \
    || echo "install-snapshot-deps: snapshot tests will skip" >&2
exit 0
