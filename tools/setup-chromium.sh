#!/usr/bin/env bash
# Headless Chromium for the report browser test (tests/framework/report/test_report_browser.py):
# Debian's 'chromium' package and a font for the page text. Idempotent: does
# nothing when a chromium binary is already on PATH.
set -euo pipefail
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    echo "setup-chromium: chromium already installed"
    exit 0
fi
echo "setup-chromium: installing chromium fonts-dejavu-core"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
$SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq --no-install-recommends chromium fonts-dejavu-core
command -v chromium >/dev/null
