"""Operator screen: time from Start pressed to the first progress update, and page weight.

Starts `station ui --sim` as its own process (default station.yaml and procedure, output to
a temp folder), opens the operator screen in Debian's chromium, and for each trial scans a
serial, presses Start and measures on the page (performance.now()):
  - ack: Start pressed -> the pushed "run" event (the page shows the run as started)
  - first progress: Start pressed -> the first pushed progress event (step "connect")
  - first engine step: Start pressed -> the engine's first step event (instruments connected)
then aborts the run and waits for ABORTED. Page weight is every byte the operator screen
loads (navigation + resources, decoded, the open event stream excluded). Targets: first
progress under 300 ms, page under 500 kB.

    python3 benchmarks/bench_ui.py [--trials 5] [--speed 100]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from station.ui.headless import chromium, chromium_missing_reason, wait_js  # noqa: E402
from station.ui.server import free_port  # noqa: E402

TARGET_MS = 300.0
TARGET_PAGE_BYTES = 500_000


def start_station(out: Path, speed: float, log_path: Path) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    cmd = [
        sys.executable,
        "-m",
        "station",
        "ui",
        "--sim",
        "--sockets",
        "1",
        "--port",
        str(port),
        "--speed",
        str(speed),
        "--out",
        str(out),
    ]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=str(ROOT), env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        if proc.poll() is not None:
            raise SystemExit(f"station ui exited: {log_path.read_text()[-2000:]}")
        try:
            httpx.get(url + "/api/state", timeout=2)
            return proc, url
        except httpx.HTTPError as exc:
            if time.monotonic() > deadline:
                proc.kill()
                raise SystemExit(
                    f"station ui did not answer: {log_path.read_text()[-2000:]}"
                ) from exc
            time.sleep(0.1)


def page_weight(page) -> tuple[int, int, list[tuple[str, int]]]:  # noqa: ANN001
    entries = page.evaluate(
        """() => [...performance.getEntriesByType('navigation'),
                  ...performance.getEntriesByType('resource')]
              .filter(e => !e.name.includes('/api/events'))
              .map(e => [e.name, e.decodedBodySize, e.transferSize])"""
    )
    decoded = sum(int(e[1]) for e in entries)
    transferred = sum(int(e[2]) for e in entries)
    return decoded, transferred, [(str(e[0]), int(e[1])) for e in entries]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--speed", type=float, default=100.0)
    args = ap.parse_args()
    reason = chromium_missing_reason()
    if reason:
        print(f"cannot run: {reason}")
        return 2
    with tempfile.TemporaryDirectory(prefix="bench-ui-") as tmp:
        proc, url = start_station(Path(tmp) / "runs", args.speed, Path(tmp) / "ui.log")
        try:
            with chromium() as browser:
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(url)
                page.wait_for_selector("#serial-1")
                page.wait_for_load_state("networkidle")
                decoded, transferred, entries = page_weight(page)
                acks, firsts, steps = [], [], []
                for k in range(args.trials):
                    page.fill("#serial-1", f"SIM-{k + 1:04d}")
                    page.press("#serial-1", "Enter")
                    page.wait_for_selector("#serial-1.ok")
                    page.click("#start-btn")
                    wait_js(page, "window.__ui.firstProgressMs !== null")
                    acks.append(page.evaluate("window.__ui.firstRunEventMs"))
                    firsts.append(page.evaluate("window.__ui.firstProgressMs"))
                    wait_js(page, "window.__ui.firstStepMs !== null")
                    steps.append(page.evaluate("window.__ui.firstStepMs"))
                    page.click("#abort-btn")
                    page.click("#abort-confirm")
                    page.wait_for_selector("#socket-1 .verdict-box:not([hidden])", timeout=60_000)
                    print(
                        f"trial {k + 1}: ack {acks[-1]:.0f} ms,"
                        f" first progress {firsts[-1]:.0f} ms,"
                        f" first engine step {steps[-1]:.0f} ms,"
                        f" verdict {page.inner_text('#socket-1 .verdict')}",
                        flush=True,
                    )
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
    print()
    print("page weight (operator screen, decoded bytes):")
    for name, size in entries:
        print(f"  {size:7d}  {name.replace(url, '')}")
    print(
        f"  {decoded:7d}  total ({transferred} bytes transferred incl. headers);"
        f" target < {TARGET_PAGE_BYTES}: {'OK' if decoded < TARGET_PAGE_BYTES else 'MISSED'}"
    )
    print()
    med = statistics.median(firsts)
    print(
        f"Start -> run acknowledged on the page: median {statistics.median(acks):.0f} ms,"
        f" max {max(acks):.0f} ms"
    )
    print(
        f"Start -> first engine step shown (after the instruments connected): median"
        f" {statistics.median(steps):.0f} ms, max {max(steps):.0f} ms"
    )
    print(
        f"Start -> first progress update on the page: median {med:.0f} ms,"
        f" max {max(firsts):.0f} ms over {len(firsts)} trials;"
        f" target < {TARGET_MS:.0f} ms: {'OK' if med < TARGET_MS else 'MISSED'}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
