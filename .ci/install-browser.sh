#!/usr/bin/env bash
# Headless Chromium for the web-viewer test (tests/integration/test_web_viewer_browser.py).
# Idempotent; never fails the build: where it cannot install, it says why on stderr and returns.
# .ci/run then checks for the browser (tests/prerequisites.py): present, the test must run
# (FXSWARM_REQUIRE_BROWSER=1); missing, .ci/run says so and lets that test skip.
# Set FXSWARM_CHROMIUM to use another browser binary.
set -u
if ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null; then
    "$(dirname "$0")/apt-install.sh" install-browser chromium || echo "install-browser: the web-viewer test will skip" >&2
fi
exit 0
