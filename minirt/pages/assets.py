"""What every evidence page shares: its images beside it, its Jinja2 environment, its display scale, and
its inline style and script.

Two kinds of page use it: the comparison report (minirt.pages.report) and the grade pages
(minirt.grading.page). Both open from disk and load nothing from the network: the style and the one
script are inline, and a Content Security Policy allows images from the page's own folder, inline styles,
and only the page's own script, by its hash (``page_parts``). Every string from a scene file, an image's
path or a student's folder is text: its control and format characters are written as escapes (the
environment's ``finalize``: minirt.io.untrusted.page_text) and its markup is escaped (autoescape). The
pictures are 8-bit PNGs at the renders' own resolution, shown at one scale (``display``) and scaled up
without smoothing; the same pixels are written once (``Assets``); every file is written atomically.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from minirt.io.atomic import atomic_path
from minirt.io.images import write_image
from minirt.io.untrusted import page_text

# Okabe-Ito colours (distinguishable with every common colour-vision deficiency).
BLUE, ORANGE, PURPLE, YELLOW, SKY = (0, 114, 178), (230, 159, 0), (204, 121, 167), (240, 228, 66), (86, 180, 233)


class Assets:
    """PNGs in one folder beside a page, linked from it as ``<href>/<name>``.

    One page (the default): identical pixels are written once, under the first name asked for, and
    ``written`` remembers every file (``prune`` removes what a previous page left). A class
    (``by_content``): every picture is named by its pixels' hash and written once into the shared
    folder, by whichever page -- in whichever worker process -- asks first (the exercise's model of a
    scene, a matching image's empty heat maps: most pages share most pictures). So the same class writes
    the same files however its pages are spread over processes."""

    def __init__(self, folder: Path, href: str = "assets", by_content: bool = False):
        self.folder, self.href, self.by_content = folder, href, by_content
        self.written: dict[str, str] = {}  # file name -> content key
        self._links: dict[str, str] = {}  # content key -> link

    def image8(self, name: str, pixels: np.ndarray) -> str:
        pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
        key = hashlib.sha256(pixels.tobytes() + str(pixels.shape).encode()).hexdigest()
        if self.by_content:
            name = f"{key[:24]}.png"
            if not _mine(self.folder / name):  # same name, same pixels: written by another page
                write_image(self.folder / name, pixels)
            return f"{self.href}/{name}"
        if key in self._links:
            return self._links[key]
        write_image(self.folder / name, pixels)
        return self._remember(name, key)

    def shared(self, name: str, pixels: np.ndarray) -> str:
        """A picture under a fixed name, the same pixels on every page: written when the folder lacks it."""
        if not _mine(self.folder / name):
            write_image(self.folder / name, pixels)
        self.written[name] = name
        return f"{self.href}/{name}"

    def figure(self, name: str, fig) -> str:
        """A matplotlib figure (PNG metadata fixed: no software version, no date)."""
        with atomic_path(self.folder / name) as tmp:
            fig.savefig(tmp, format="png", metadata={"Software": None})
        return self._remember(name, name)

    def copy(self, name: str, src: Path) -> str:
        with atomic_path(self.folder / name) as tmp:
            shutil.copyfile(src, tmp)
        return self._remember(name, name)

    def _remember(self, name: str, key: str) -> str:
        self.written[name] = key
        self._links[key] = f"{self.href}/{name}"
        return f"{self.href}/{name}"

    def prune(self) -> None:
        """Remove PNGs a previous page left in the folder (never call it on a folder pages share)."""
        for p in self.folder.glob("*.png"):
            if p.name not in self.written:
                p.unlink()


class InlineAssets:
    """Pictures inside the page itself, as ``data:`` URIs (the Content Security Policy allows them): a page
    that is one file. The PNGs are the bytes ``Assets`` would write (minirt.io.images.write_image, into a
    temporary folder and read back); identical pixels are encoded once."""

    def __init__(self) -> None:
        self._uris: dict[str, str] = {}

    def image8(self, name: str, pixels: np.ndarray) -> str:
        from minirt.jobs.processes import temporary_folder

        pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
        key = hashlib.sha256(pixels.tobytes() + str(pixels.shape).encode()).hexdigest()
        if key not in self._uris:
            with temporary_folder("minirt-page-") as tmp:
                write_image(tmp / "picture.png", pixels)
                data = (tmp / "picture.png").read_bytes()
            self._uris[key] = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
        return self._uris[key]

    def shared(self, name: str, pixels: np.ndarray) -> str:
        return self.image8(name, pixels)


def _mine(path: Path) -> bool:
    """Is ``path`` a file of its own (not a symlink planted under its name, which is replaced)?"""
    return path.is_file() and not path.is_symlink()


def highlight(base8: np.ndarray, mask: np.ndarray, rgb: tuple[int, int, int] = YELLOW) -> np.ndarray:
    """An 8-bit image darkened to a quarter, the mask's pixels painted in ``rgb`` (the pixels a rule
    explains or changes)."""
    out = base8.astype(np.float64) * 0.25
    out[mask] = rgb
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def display(w: int, h: int, tile: int) -> dict[str, Any]:
    """How a page shows a w×h image: its longest side about ``tile`` CSS pixels, at a whole scale when
    that enlarges it (then drawn without smoothing: ``pixelated``) so every pixel is a square block."""
    s = tile / max(w, h, 1)
    s = float(math.floor(s)) if s >= 1 else s
    return {"scale": s, "w": round(w * s), "h": round(h * s), "pixelated": s >= 1}


def _shown(value: Any) -> Any:
    """Every value a template prints: a string, unless already markup (the page's own style and script),
    goes through minirt.io.untrusted.page_text -- no raw ESC, BEL, NUL or bidi override reaches a page."""
    import markupsafe

    return page_text(value) if isinstance(value, str) and not isinstance(value, markupsafe.Markup) else value


@functools.cache
def environment():
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("minirt.pages", "templates"),
        autoescape=True,  # every string from a scene, a path or a folder name is text, never markup
        finalize=_shown,  # ... and its control characters are escapes (minirt.io.untrusted.page_text)
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )


@functools.cache
def page_parts(script: str, *styles: str) -> dict[str, Any]:
    """A page's inline script and style from their templates, and the script's hash, which the page's
    Content Security Policy names as the only script it runs."""
    import markupsafe

    env = environment()
    js = env.get_template(script).render()
    css = "".join(env.get_template(s).render() for s in styles)
    return {
        "style": markupsafe.Markup(css),
        "script": markupsafe.Markup(js),
        "csp_hash": base64.b64encode(hashlib.sha256(js.encode()).digest()).decode(),
    }


def write_page(path: Path, template: str, parts: dict[str, Any], **context: Any) -> None:
    """Render a page's template with its parts (``page_parts``) and write it atomically."""
    html = environment().get_template(template).render(**parts, **context)
    with atomic_path(path) as tmp:
        tmp.write_text(html, encoding="utf-8")
