#!/usr/bin/env bash
# Regenerates docs/img/*.png: the shipped example replayed with the paper's model
# (`g1viz replay examples/g1_example.mcap --model paper`), one screenshot per tab of the layout,
# and a plain replay of it (no model) on its Joints tab,
# taken in the stock Rerun 0.36.3 web viewer in headless Chromium (software WebGL under Xvfb).
#
# Needs: cargo; `pip install rerun-sdk==0.36.3 websocket-client`; Debian packages
# `xvfb chromium`. Run from anywhere: docs/screenshots.sh [WAIT_SECONDS]
set -euo pipefail
cd "$(dirname "$0")/.."
wait_s="${1:-150}"
work="$(mktemp -d)"
pids=()
xvfb=""
cleanup() {
    # The `rerun` launchers and the viewer each started.
    for p in "${pids[@]}"; do pkill -P "$p" 2>/dev/null || true; kill "$p" 2>/dev/null || true; done
    # xvfb-run stops neither the browser nor its X server when it is killed: stop its children
    # (the browser, Xvfb), then it.
    if [ -n "$xvfb" ]; then
        pkill -P "$xvfb" 2>/dev/null || true
        kill "$xvfb" 2>/dev/null || true
        wait "$xvfb" 2>/dev/null || true
    fi
    # The browser's helper processes may still be writing its cache for a moment.
    for _ in 1 2 3 4 5; do rm -rf "$work" 2>/dev/null && break; sleep 1; done
}
trap cleanup EXIT

cargo run --quiet --example docs_views -- "$work/rrd" > "$work/list.tsv"
# A plain replay (no model: the file is streamed, its layout sent again once the data is in),
# on its Joints tab.
cargo run --quiet -- replay examples/g1_example.mcap --max-rate 25 --pose-rate 25 \
    --open-tab Joints --save "$work/rrd/6-plain-replay-joints.rrd"
printf '%s\t%s\n' "$work/rrd/6-plain-replay-joints.rrd" "plain replay, Joints" >> "$work/list.tsv"
mkdir -p docs/img

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
devtools="$(free_port)"
xvfb-run -a -s "-screen 0 1920x1080x24" chromium --headless --no-sandbox \
    --use-gl=angle --use-angle=swiftshader --enable-unsafe-swiftshader --ignore-gpu-blocklist \
    --disable-background-networking --disable-component-update --no-first-run \
    --user-data-dir="$work/chrome" --window-size=1920,1080 \
    --remote-allow-origins="*" --remote-debugging-port="$devtools" about:blank > "$work/chrome.log" 2>&1 &
xvfb=$!
for _ in $(seq 50); do curl -s "http://127.0.0.1:$devtools/json" > /dev/null && break; sleep 0.2; done

while IFS=$'\t' read -r rrd tab; do
    name="$(basename "$rrd" .rrd)"
    grpc="$(free_port)"; web="$(free_port)"
    rerun --serve-web "$rrd" --port "$grpc" --web-viewer-port "$web" > "$work/$name.log" 2>&1 &
    server=$!
    pids+=("$server")
    for _ in $(seq 100); do curl -s "http://127.0.0.1:$web" > /dev/null && break; sleep 0.2; done
    url="http://127.0.0.1:$web/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$grpc%2Fproxy"
    python3 docs/cdp_screenshot.py "$devtools" "$wait_s" "$url" "docs/img/$name.png"
    # `rerun` on PATH is a launcher: stop the viewer binary it started, then the launcher.
    pkill -P "$server" 2>/dev/null || true
    kill "$server" 2>/dev/null || true
    wait "$server" 2>/dev/null || true
    echo "$name: $tab"
done < "$work/list.tsv"
