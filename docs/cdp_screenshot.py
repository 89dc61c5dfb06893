"""Photograph pages in a running headless Chromium through the DevTools protocol.

python3 cdp_screenshot.py DEVTOOLS_PORT WAIT_S URL OUT.png [URL OUT.png ...]

Each URL is loaded in the first page target, given WAIT_S seconds of real time (the Rerun web
viewer compiles its WebAssembly and streams the recording; a virtual-time budget does not cover
that), then captured as PNG. Needs `websocket-client` (pip).
"""
import base64
import json
import sys
import time
import urllib.request

import websocket


def main():
    port, wait = sys.argv[1], float(sys.argv[2])
    jobs = list(zip(sys.argv[3::2], sys.argv[4::2]))
    targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json"))
    page = next(t for t in targets if t["type"] == "page")
    ws = websocket.create_connection(page["webSocketDebuggerUrl"], timeout=300)
    counter = [0]

    def call(method, **params):
        counter[0] += 1
        ws.send(json.dumps({"id": counter[0], "method": method, "params": params}))
        while True:
            msg = json.loads(ws.recv())
            if msg.get("id") == counter[0]:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    call("Page.enable")
    for url, out in jobs:
        call("Page.navigate", url=url)
        time.sleep(wait)
        # The viewer fits a plot's y axis to what it drew the frame before and does not redraw
        # a page nobody touches: a pointer move over the selection panel (off the plots) makes
        # it draw fitted frames.
        for x, y in ((1500, 600), (1510, 610)):
            call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
            time.sleep(1.5)
        data = call("Page.captureScreenshot", format="png")["data"]
        with open(out, "wb") as f:
            f.write(base64.b64decode(data))
        print("wrote", out, flush=True)


if __name__ == "__main__":
    main()
