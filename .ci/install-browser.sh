#!/usr/bin/env bash
# Headless Chromium for the web-viewer test (tests/integration/test_web_viewer_browser.py).
# Idempotent. Where Chromium is there or apt-get installs it (root, or passwordless sudo), prints
# "required" on stdout so .ci/run sets FXSWARM_REQUIRE_BROWSER=1 and the test fails rather than
# skips without it; elsewhere it says why on stderr and the test skips (rather than CI failing
# on a package source that did not answer). Set FXSWARM_CHROMIUM to use another browser binary.
set -u
if command -v chromium >/dev/null || command -v chromium-browser >/dev/null \
        || "$(dirname "$0")/apt-install.sh" install-browser chromium; then
    echo required
else
    echo "install-browser: the web-viewer test will skip" >&2
fi
exit 0
