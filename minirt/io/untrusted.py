"""Untrusted text: the one place where text from a scene file, a file name or a renderer's output becomes
text for a terminal or a file name.

A scene's name, a student's folder or POV-Ray's error message can hold anything: Rich markup
(``x[/]``, ``[link=file:///etc/passwd]``), escape sequences that retitle or clear a terminal, NUL,
bidirectional overrides, path separators, ``..``, a spreadsheet formula (``=HYPERLINK(...)``). These
functions, and nobody else, turn such text into text for a terminal, a page, a CSV cell or a file name:

- :func:`terminal_text` -- for the console (Rich markup): control and format characters written as
  ``\\x1b`` / ``\\u202e`` escapes, markup escaped, very long text cut (with the count of what was cut).
- :func:`page_text` -- for an HTML page (every string a page template shows, before Jinja2's
  autoescape): the same escapes, newlines kept (a description's lines), nothing cut.
- :func:`xml_text` -- for XML (JUnit): the same escapes (XML 1.0 forbids NUL, ESC, BEL and most other
  controls), newlines kept, nothing cut; ElementTree escapes the markup.
- :func:`csv_cell` -- for a CSV cell: the same escapes, and a cell a spreadsheet would evaluate as a
  formula neutralised by OWASP's rule (a leading ``'``).
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


_ESCAPED = frozenset(("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"))  # Unicode categories written as escapes


def printable(text: object, limit: int | None = MAX_SHOWN, keep: str = "") -> str:
    """``text`` with every character a terminal would act on written as an escape: C0/C1 controls
    (ESC, BEL, CR, newline), DEL, format characters (bidi overrides, zero-width) and lone surrogates (the
    bytes of non-UTF-8 input decoded with ``surrogateescape``) -- no markup handling. ``limit``: characters
    shown, the rest counted (None: all); ``keep``: characters left as they are (a page keeps newlines)."""
    s = str(text)
    cut = len(s) - limit if limit is not None and len(s) > limit else 0
    if cut:
        s = s[:limit]
    out = s if s.isprintable() else "".join(_escape(c, keep) for c in s)  # isprintable: none to escape
    return f"{out}... ({cut} more characters)" if cut else out


def _escape(c: str, keep: str) -> str:
    if unicodedata.category(c) not in _ESCAPED or c in keep:
        return c
    o = ord(c)
    if 0xDC80 <= o <= 0xDCFF:  # surrogateescape: the original byte
        return f"\\x{o - 0xDC00:02x}"
    if o < 0x100:
        return f"\\x{o:02x}"
    return f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}"


def terminal_text(text: object, limit: int = MAX_SHOWN) -> str:
    """Untrusted text inside a Rich markup string: printable (see :func:`printable`) and markup-escaped,
    so ``[red]x`` or ``x[/]`` prints as those characters."""
    from rich.markup import escape

    return escape(printable(text, limit))


def page_text(text: str) -> str:
    """Untrusted text for an HTML page, before Jinja2's autoescape (which makes ``<``, ``&`` and quotes
    text): control and format characters written as escapes, as on a terminal (:func:`printable`), so a
    page holds no raw ESC, BEL, NUL or tab, no bidi override that reorders what it shows, and no lone
    surrogate (which UTF-8 cannot encode); newlines are kept (a scene's description is shown as written),
    nothing is cut."""
    return printable(text, None, keep="\n")


def xml_text(text: object) -> str:
    """Untrusted text for XML 1.0 (JUnit's attributes; ElementTree then escapes ``<``, ``&`` and quotes):
    XML 1.0 forbids most control characters (NUL, ESC, BEL: a parser rejects the whole file), lone
    surrogates and U+FFFE/U+FFFF, so they -- and the other characters a terminal would act on -- are
    written visibly as ``\\x1b``-style escapes (:func:`printable`), newlines kept, nothing cut."""
    return printable(text, None, keep="\n")


# OWASP (CSV Injection): a cell starting with one of these is a formula to a spreadsheet (Excel,
# LibreOffice Calc, Google Sheets): =HYPERLINK(...), +SUM(1,2), @SUM(1), -2+3, a tab or a carriage return.
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value: object) -> str:
    """A CSV cell from untrusted text: control and format characters written as escapes
    (:func:`printable`, nothing cut: no raw ESC, NUL or line break inside a cell), then, when the cell
    starts with a character a spreadsheet evaluates (``FORMULA_START``), a leading ``'`` -- OWASP's rule:
    a spreadsheet reads the cell as text, never as a formula. The csv module then quotes
    commas and quotes (RFC 4180)."""
    s = printable(value, None)
    return f"'{s}" if s.startswith(FORMULA_START) else s


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
