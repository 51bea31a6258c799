#!/usr/bin/env python3
"""Screenshot every report page (index.html) under DIR into OUT with headless Chromium, so a
person can look at what a reader sees (layout, thumbnails, headline) without opening a browser.

    python scripts/screenshot_reports.py demo demo/screenshots

One PNG per page, named after its folder (``index.png`` for DIR/index.html itself,
``report_train.png`` for DIR/report_train/index.html). Chromium is not a dependency of the
package and CI does not need it: install it with ``apt-get install -y chromium`` (Debian/Ubuntu);
without it the script says so in one line and exits 0 (nothing to do), so that it can sit in a
workflow that does not have it. Exit 2: DIR is not a directory or holds no index.html.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: Where Debian's package puts it; other names are looked up on PATH.
CHROMIUM = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome")
#: A laptop's width, tall enough for a report's headline, contents and first figures.
WINDOW = "1280,2000"
#: Seconds one page may take (a page with ten 100 kB figures renders in one or two).
TIMEOUT_S = 60.0


def find_chromium() -> str | None:
    """The Chromium executable, or None."""
    for name in CHROMIUM:
        path = name if os.path.isabs(name) and os.access(name, os.X_OK) else shutil.which(name)
        if path:
            return path
    return None


def pages(directory: Path) -> list[Path]:
    """Every index.html under ``directory``, the top one first."""
    return sorted(directory.rglob("index.html"), key=lambda p: (len(p.relative_to(directory).parts), str(p)))


def shot_name(directory: Path, page: Path) -> str:
    rel = page.parent.relative_to(directory)
    return ("index" if rel == Path(".") else "_".join(rel.parts)) + ".png"


def screenshot(chromium: str, page: Path, out: Path, window: str = WINDOW) -> None:
    """One headless screenshot of ``page`` into ``out`` (a fresh profile each time: no state,
    no network, no first-run dialogs)."""
    with tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile:
        cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--hide-scrollbars", f"--user-data-dir={profile}", f"--screenshot={out}",
               f"--window-size={window}", page.resolve().as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S, check=False)
    if proc.returncode != 0 or not out.is_file():
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"{page}: chromium exit {proc.returncode}: {last}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="screenshot every index.html under DIR into OUT (headless Chromium)")
    p.add_argument("directory", metavar="DIR", help="a report folder, or a folder of reports (demo/)")
    p.add_argument("out", metavar="OUT", help="folder for the PNGs (created)")
    p.add_argument("--window-size", default=WINDOW, metavar="W,H", help=f"browser window in pixels (default {WINDOW})")
    args = p.parse_args(argv)
    directory, out = Path(args.directory), Path(args.out)
    if not directory.is_dir():
        print(f"screenshot_reports: error: {directory}: not a directory", file=sys.stderr)
        return 2
    found = pages(directory)
    if not found:
        print(f"screenshot_reports: error: {directory}: no index.html in it or below", file=sys.stderr)
        return 2
    chromium = find_chromium()
    if chromium is None:
        print("screenshot_reports: skipped: no Chromium found (install it with `apt-get install -y chromium`)")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    for page in found:
        target = out / shot_name(directory, page)
        try:
            screenshot(chromium, page, target, args.window_size)
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            print(f"screenshot_reports: error: {exc}", file=sys.stderr)
            return 1
        print(target)
    return 0


if __name__ == "__main__":
    sys.exit(main())
