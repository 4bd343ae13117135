"""Screenshot a web page in headless Chromium once it has had time to run (CDP).

How docs/img/rerun-run-mcap.png and rerun-ctl-mcap.png were made (Debian's ``chromium``,
``pip install rerun-sdk``; software rendering, so the viewer's WebGL renderer)::

    tfl-mav demo paper --out demo
    rerun mcap convert demo/run.mcap -o demo/run.rrd
    rerun --web-viewer --web-viewer-port 9090 --port 9877 demo/run.rrd &
    python docs/img/screenshot.py \\
        "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2Flocalhost%3A9877%2Fproxy&renderer=webgl" \\
        docs/img/rerun-run-mcap.png 60

(the same with ``ctl.mcap`` for the controller's). Usage: ``python docs/img/screenshot.py
URL OUT.png WAIT_S [WIDTHxHEIGHT]``.
"""

from __future__ import annotations

import asyncio
import base64
import json
import subprocess
import sys
import time
import urllib.request
from typing import Any

import websockets

_PORT = 9333


def _page_socket() -> str:
    for _ in range(100):
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{_PORT}/json") as r:
                tabs = json.load(r)
            return next(t["webSocketDebuggerUrl"] for t in tabs if t["type"] == "page")
        except (OSError, StopIteration):
            time.sleep(0.2)
    raise RuntimeError("chromium did not open its debugging port")


async def _shoot(ws_url: str, url: str, out: str, wait_s: float, w: int, h: int) -> None:
    async with websockets.connect(ws_url, max_size=2**27) as ws:
        ids = iter(range(1, 1 << 30))

        async def call(method: str, **params: Any) -> dict[str, Any]:
            n = next(ids)
            await ws.send(json.dumps({"id": n, "method": method, "params": params}))
            while True:
                msg = json.loads(await ws.recv())
                if msg.get("id") == n:
                    return msg

        await call("Emulation.setDeviceMetricsOverride", width=w, height=h,
                   deviceScaleFactor=1, mobile=False)
        await call("Page.navigate", url=url)
        await asyncio.sleep(wait_s)
        shot = await call("Page.captureScreenshot", format="png")
        with open(out, "wb") as f:
            f.write(base64.b64decode(shot["result"]["data"]))


def main() -> int:
    url, out, wait_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
    w, h = (int(x) for x in (sys.argv[4] if len(sys.argv) > 4 else "1600x1000").split("x"))
    proc = subprocess.Popen(["chromium", "--headless=new", "--no-sandbox",
                             "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                             f"--window-size={w},{h}", f"--remote-debugging-port={_PORT}",
                             "--remote-debugging-address=127.0.0.1", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        asyncio.run(_shoot(_page_socket(), url, out, wait_s, w, h))
    finally:
        proc.terminate()
        proc.wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
