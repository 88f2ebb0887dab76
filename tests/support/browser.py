"""Headless Chromium for the tests that open a page as a reader would: the DOM after the load event with
the self-check the page's own script writes on <body>, the console, and a screenshot."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from minirt.io.images import read_image_u8


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    pytest.fail("no headless browser: `make setup` installs Debian's chromium")


def run_browser(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--no-first-run", "--disable-component-update", "--disable-sync", f"--user-data-dir={tmp / 'profile'}",
           "--enable-logging=stderr", "--v=0", *args]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, timeout=90, check=False, cwd=tmp)


def loaded_page(tmp: Path, url: str, body_attr: str) -> tuple[subprocess.CompletedProcess, dict[str, str]]:
    """The DOM after the load event (``--dump-dom``) and the attributes of its <body>, found by an attribute
    (``body_attr``) the page's self-check writes there."""
    dom = run_browser(tmp, "--dump-dom", url)
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(rf"<body\b[^>]*\b{body_attr}=[^>]*>", dom.stdout)
    assert body, dom.stdout[:2000]
    return dom, dict(re.findall(r'([\w-]+)="([^"]*)"', body.group(0)))


def assert_all_images_loaded(attrs: dict[str, str], html: str) -> None:
    """The self-check counted every <img> of the page, and every one loaded."""
    loaded, total = map(int, attrs["data-images-loaded"].split("/"))
    assert total == len(re.findall(r"<img\b", html)) and loaded == total, attrs


def console(dom: subprocess.CompletedProcess) -> list[str]:
    """Chromium logs every console message (errors, CSP refusals) as "CONSOLE" on stderr."""
    return [ln for ln in dom.stderr.splitlines() if ":CONSOLE" in ln]


def screenshot(tmp: Path, url: str, width: int, height: int) -> np.ndarray:
    """The page in a width x height window, as 8-bit RGB."""
    shot = tmp / "shot.png"
    r = run_browser(tmp, f"--screenshot={shot}", f"--window-size={width},{height}", url)
    assert r.returncode == 0 and shot.is_file(), r.stderr[-2000:]
    return read_image_u8(shot)[..., :3]


def distinct_colours(px: np.ndarray) -> int:
    """How many RGB colours an 8-bit picture holds: each pixel's 24 bits as an index into a table of 2^24
    flags -- np.unique(axis=0) sorts the rows instead, seconds of CPU for a screenshot's millions."""
    rgb = px[..., :3].reshape(-1, 3).astype(np.uint32)
    seen = np.zeros(1 << 24, bool)
    seen[(rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]] = True
    return int(np.count_nonzero(seen))
