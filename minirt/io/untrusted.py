"""Untrusted text: the one place where text from a scene file, a file name or a renderer's output becomes
text for a terminal or a file name.

A scene's name, a student's folder or POV-Ray's error message can hold anything: Rich markup
(``x[/]``, ``[link=file:///etc/passwd]``), escape sequences that retitle or clear a terminal, NUL,
bidirectional overrides, path separators, ``..``. Two functions, and nobody else prints or names files
from such text:

- :func:`terminal_text` -- for the console (Rich markup): control and format characters written as
  ``\\x1b`` / ``\\u202e`` escapes, markup escaped, very long text cut (with the count of what was cut).
- :func:`file_stem` -- for a file name inside an output folder: portable characters only, never empty,
  never ``.``/``..`` or hidden, bounded length (a hash of the whole keeps two long names apart);
  :func:`name_part` for the parts of a name after its stem (a variant's ``rule=value`` tags).
"""

from __future__ import annotations

import hashlib
import re
import unicodedata

MAX_SHOWN = 400  # characters of one untrusted value on a terminal line; the rest is counted, not shown
MAX_STEM = 80  # characters of a file stem from a scene name (file systems allow 255 bytes per name)
_STEM_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
_PART_UNSAFE = re.compile(r"[^A-Za-z0-9._,=-]")  # a tag part may also say rule=value,value


def printable(text: object, limit: int = MAX_SHOWN) -> str:
    """``text`` with every character a terminal would act on written as an escape: C0/C1 controls
    (ESC, BEL, CR, newline), DEL, format characters (bidi overrides, zero-width) and lone surrogates (the
    bytes of non-UTF-8 input decoded with ``surrogateescape``) -- no markup handling."""
    s = str(text)
    cut = len(s) - limit if len(s) > limit else 0
    if cut:
        s = s[:limit]
    parts = []
    for c in s:
        cat = unicodedata.category(c)
        if cat in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"):
            o = ord(c)
            if 0xDC80 <= o <= 0xDCFF:  # surrogateescape: the original byte
                parts.append(f"\\x{o - 0xDC00:02x}")
            elif o < 0x100:
                parts.append(f"\\x{o:02x}")
            else:
                parts.append(f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}")
        else:
            parts.append(c)
    out = "".join(parts)
    return f"{out}... ({cut} more characters)" if cut else out


def terminal_text(text: object, limit: int = MAX_SHOWN) -> str:
    """Untrusted text inside a Rich markup string: printable (see :func:`printable`) and markup-escaped,
    so ``[red]x`` or ``x[/]`` prints as those characters."""
    from rich.markup import escape

    return escape(printable(text, limit))


def file_stem(name: object, fallback: str = "scene") -> str:
    """A file stem from untrusted text (a scene's name): runs of characters outside ``A-Za-z0-9._-``
    become one ``_``; runs of dots become one; leading dots, dashes and ``_`` go (no hidden files,
    no ``..``, no option-like names);
    longer than MAX_STEM is cut and given a hash of the whole; empty becomes ``fallback``."""
    s = str(name)
    stem = re.sub(r"\.{2,}", ".", _STEM_UNSAFE.sub("_", s)).lstrip("._-")
    if len(stem) > MAX_STEM:
        digest = hashlib.sha256(s.encode("utf-8", "surrogatepass")).hexdigest()[:12]
        stem = f"{stem[: MAX_STEM - 13]}_{digest}"
    return stem.rstrip("_") or fallback


def name_part(text: object) -> str:
    """A part of a file name after a safe stem (minirt.io.names' ``rule=value`` tags, joined by ``+``):
    every character outside ``A-Za-z0-9._,=-`` becomes ``_`` -- no separator, no ``+``, nothing a shell
    or a file system reads. Its place after the stem keeps it from making a hidden or ``..`` name."""
    return _PART_UNSAFE.sub("_", str(text))
