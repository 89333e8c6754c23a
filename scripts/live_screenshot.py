#!/usr/bin/env python3
"""The live page mid-episode, two checkpoints side by side: docs/live.png.

Starts `orchestrator live` with the two checkpoints and headless Chromium through chromedriver
(both installed by scripts/setup.sh), starts PROGRAM with the first checkpoint and the second
beside it, takes STEPS steps, and saves the window. WebDriver is spoken over plain HTTP, so
nothing beyond Python's standard library is needed.

    python3 scripts/live_screenshot.py --checkpoint RUN_A --beside RUN_B --program val:27 \
        --steps 20 --out docs/live.png
"""
import argparse
import base64
import json
import socket
import subprocess
import tempfile
import time
import urllib.request


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--orchestrator", default="target/release/orchestrator")
    p.add_argument("--checkpoint", required=True)
    p.add_argument("--beside", required=True)
    p.add_argument("--program", default="val:27")
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--out", default="docs/live.png")
    a = p.parse_args()

    records = tempfile.mkdtemp(prefix="gesthor-live-shot-")
    server = subprocess.Popen(
        [a.orchestrator, "live", "--checkpoint", a.checkpoint, "--checkpoint", a.beside,
         "--listen", f"127.0.0.1:{free_port()}", "--out", records],
        stdout=subprocess.PIPE, text=True)
    url = next(w for w in server.stdout.readline().split() if w.startswith("http://"))
    port = free_port()
    driver = subprocess.Popen(["/usr/bin/chromedriver", f"--port={port}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def call(method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", method=method, data=data,
                                     headers={"Content-Type": "application/json"})
        return json.loads(urllib.request.urlopen(req).read())["value"]

    try:
        for _ in range(100):
            try:
                call("GET", "/status")
                break
            except OSError:
                time.sleep(0.1)
        options = {"binary": "/usr/bin/chromium", "args": [
            "--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1400,1250", "--hide-scrollbars"]}
        sid = call("POST", "/session", {"capabilities": {"alwaysMatch": {"goog:chromeOptions": options}}})["sessionId"]

        def js(expr):
            return call("POST", f"/session/{sid}/execute/sync", {"script": "return " + expr, "args": []})

        def wait(expr):
            for _ in range(1200):
                v = js(expr)
                if v:
                    return v
                time.sleep(0.25)
            raise SystemExit(f"the page never showed `{expr}` (its errors: {js('window.live.errors')})")

        call("POST", f"/session/{sid}/url", {"url": url})
        wait("window.live && window.live.session")
        split, index = a.program.split(":")
        js(f"(document.getElementById('checkpoint').value = '0', document.getElementById('versus').value = '1', "
           f"document.getElementById('split').value = '{split}', document.getElementById('index').value = '{index}', "
           "document.getElementById('start').click(), true)")
        wait("window.live.episode")
        for k in range(a.steps):
            if js("window.live.ended"):
                break
            js("(document.getElementById('step').click(), true)")
            wait(f"window.live.sides.every(s => s.end || s.steps >= {k + 1})")
        time.sleep(1.5)  # the person's film plays on, the pictures load
        shown = js("window.live.sides.map(s => s.shown)")
        with open(a.out, "wb") as f:
            f.write(base64.b64decode(call("GET", f"/session/{sid}/screenshot")))
        call("DELETE", f"/session/{sid}")
        print(f"{a.out}: {a.program} after {a.steps} steps, gestures shown {shown} (records in {records})")
    finally:
        driver.kill()
        server.kill()


if __name__ == "__main__":
    main()
