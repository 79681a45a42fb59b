#!/usr/bin/env bash
# Installs Debian's headless Chromium and its WebDriver (chromium, chromium-driver),
# which tools/screenshots.py and tools/bench_view.py drive to look at Rerun's web
# viewer. Does nothing when both are there. Needs apt-get (run as root or with sudo).
set -euo pipefail
if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then
  exit 0
fi
sudo=""
if [ "$(id -u)" != 0 ]; then
  command -v sudo >/dev/null || { echo "install_chromium: run as root (apt-get needs it)" >&2; exit 2; }
  sudo=sudo
fi
echo "install_chromium: installing chromium and chromium-driver from Debian's packages" >&2
$sudo apt-get update -q >/dev/null
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends \
  chromium chromium-driver fonts-dejavu-core >/dev/null
command -v chromedriver >/dev/null || { echo "install_chromium: chromedriver missing after install" >&2; exit 1; }
