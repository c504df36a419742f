#!/usr/bin/env bash
# Screenshots of the built docs site in headless Chromium (Debian's package),
# for docs/img/site-*.png:  make docs && bash scripts/docs_screenshots.sh
set -euo pipefail
cd "$(dirname "$0")/.."
SITE=docs/_build/html
[ -f "$SITE/index.html" ] || { echo "docs_screenshots: build the site first: make docs" >&2; exit 2; }
if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null
  else
    echo "docs_screenshots: needs Chromium:  sudo apt-get install -y chromium" >&2; exit 1
  fi
fi
PORT=${PORT:-8765}
.venv/bin/python -m http.server "$PORT" --directory "$SITE" >/dev/null 2>&1 &
server=$!
trap 'kill $server' EXIT
sleep 1
profile=$(mktemp -d)
shot() {  # shot PAGE OUT.png [HEIGHT]
  chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run \
    --disable-background-networking --disable-component-update --disable-sync \
    --user-data-dir="$profile" --hide-scrollbars --window-size=1280,"${3:-1000}" \
    --screenshot="$2" "http://127.0.0.1:$PORT/$1" >/dev/null 2>&1
  echo "docs_screenshots: $2"
}
shot index.html docs/img/site-front.png
shot tutorials/decompose.html docs/img/site-tutorial.png
shot reference/api/tlsvox.html docs/img/site-api.png
shot reference/cli.html docs/img/site-cli.png
shot howto/echo_weights.html docs/img/site-howto.png
shot benchmarks.html docs/img/site-benchmarks.png
