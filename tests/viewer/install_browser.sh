#!/usr/bin/env bash
# What the real-browser viewer test needs: Debian's chromium + Node.js, and playwright-core from npm
# under .cache/node (git-ignored). Installed only when missing; without root (no apt-get) it says what
# is missing and the browser test is skipped outside CI (and fails in CI, where this must work).
set -euo pipefail
cd "$(dirname "$0")/../.."
PLAYWRIGHT_VERSION=1.65.1
missing=()
command -v chromium >/dev/null 2>&1 || [ -x /usr/bin/chromium ] || missing+=(chromium)
command -v node >/dev/null 2>&1 || missing+=(nodejs)
command -v npm >/dev/null 2>&1 || missing+=(npm)
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing ${missing[*]} (apt-get) for the browser test"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  else
    echo "note: ${missing[*]} missing and not root: the viewer's browser test will be skipped" >&2
    exit 0
  fi
fi
if [ ! -f .cache/node/node_modules/playwright-core/package.json ]; then
  echo "installing playwright-core@${PLAYWRIGHT_VERSION} (npm) into .cache/node for the browser test"
  npm install --silent --no-audit --no-fund --prefix .cache/node "playwright-core@${PLAYWRIGHT_VERSION}"
fi
