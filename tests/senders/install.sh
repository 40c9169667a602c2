#!/usr/bin/env bash
# Installs the G-code senders that tests/senders drives against the grbl server:
#   Debian: Node.js 20 or later and npm (cncjs, playwright-core), chromium (cncjs's page,
#           driven headless), udev (udevadm: cncjs lists serial ports with it);
#   npm:    cncjs, socket.io-client and playwright-core, pinned by package-lock.json, into
#           tests/senders/node_modules (never a browser download: the system's chromium);
#   PyPI:   grbl-streamer, into the project's virtual environment.
# Debian packages need root; without it the script says what to install and stops.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
python="${PYTHON:-$root/.venv/bin/python}"
GRBL_STREAMER_VERSION=2.0.2

missing=()
command -v node > /dev/null || missing+=(nodejs)
command -v npm > /dev/null || missing+=(npm)
command -v chromium > /dev/null || missing+=(chromium)
command -v udevadm > /dev/null || missing+=(udev)
if ((${#missing[@]})); then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -q
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
  else
    echo "tests/senders/install.sh: as root, run: apt-get install ${missing[*]}" >&2
    exit 1
  fi
fi

node_major="$(node -p 'process.versions.node.split(".")[0]')"
if [ "$node_major" -lt 20 ]; then
  echo "tests/senders/install.sh: Node.js $(node --version) is too old; playwright-core" \
       "needs 20 or later" >&2
  exit 1
fi

cd "$here"
if [ ! -f node_modules/.package-lock.json ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
  npm ci --no-audit --no-fund --loglevel=error
fi

"$python" -m pip install --quiet --disable-pip-version-check "grbl-streamer==$GRBL_STREAMER_VERSION"
echo "tests/senders/install.sh: cncjs $(node -p 'require("cncjs/package.json").version')," \
     "playwright-core $(node -p 'require("playwright-core/package.json").version')," \
     "grbl-streamer $GRBL_STREAMER_VERSION, $(chromium --version 2> /dev/null | head -1)"
