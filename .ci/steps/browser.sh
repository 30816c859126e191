#!/usr/bin/env bash
# CI step: the dashboard in headless Chromium (tests/browser/run.sh), which
# also regenerates docs/img/dashboard.png, the README's screenshot. Installs
# Debian's chromium (and python3/curl) when missing; prints a SKIPPED line
# and succeeds when they cannot be installed.
set -euo pipefail
cd "$(dirname "$0")/../.."

need=()
command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || need+=(chromium)
command -v python3 >/dev/null 2>&1 || need+=(python3)
command -v curl >/dev/null 2>&1 || need+=(curl)
if [ ${#need[@]} -gt 0 ]; then
  sudo=
  if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
      sudo="sudo -n"
    else
      echo "SKIPPED: dashboard browser test (missing ${need[*]}; not root and no sudo to install them)"
      exit 0
    fi
  fi
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "SKIPPED: dashboard browser test (missing ${need[*]} and no apt-get)"
    exit 0
  fi
  echo "installing ${need[*]}"
  if ! { $sudo apt-get update -qq &&
         DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
           "${need[@]}" fonts-dejavu-core >/dev/null; }; then
    echo "SKIPPED: dashboard browser test (apt-get install ${need[*]} failed)"
    exit 0
  fi
fi
chromium=$(command -v chromium || command -v chromium-browser || true)
if [ -z "$chromium" ] || ! timeout 60 "$chromium" --headless --no-sandbox --disable-gpu --version >/dev/null 2>&1; then
  echo "SKIPPED: dashboard browser test (chromium is installed but does not start)"
  exit 0
fi

# Regenerates the README's screenshot; a changed image shows in git status.
CHROMIUM=$chromium SCREENSHOT=docs/img/dashboard.png bash tests/browser/run.sh
