"""Which Mitsuba: the package (version PACKAGE_VERSION, imported once per process) and the first
usable of VARIANTS -- ``llvm_ad_rgb``, or ``scalar_rgb`` when Dr.Jit's LLVM backend is unusable (a
per-ray loop, correct but slow). The choice is process-wide (Mitsuba's variant is global state), kept
in ``_state``; every render re-selects it in case another caller switched. To narrow the choice, set
this module's VARIANTS (the package re-exports it, but only this one is read).

Mitsuba's log (its warnings: a ball scaled past float32's range) is routed to Python's warnings
(``_log_as_warnings``), one line each without Mitsuba's date and colour codes: minirt's command line
prints them as its own warning lines, a program using minirt sees ordinary Python warnings.
"""

from __future__ import annotations

import contextlib
import re
from typing import Any

BACKEND = "mitsuba"
PACKAGE_VERSION = "3.9.1"
VARIANTS = ("llvm_ad_rgb", "scalar_rgb")  # preferred first

_state: dict[str, Any] = {}


def load_mitsuba() -> tuple[Any, str]:
    """Import mitsuba and set the first usable variant; raises ImportError/RuntimeError with a reason."""
    if "mi" in _state:
        mi = _state["mi"]
        if mi.variant() != _state["variant"]:
            mi.set_variant(_state["variant"])
        return mi, _state["variant"]
    import mitsuba as mi

    _log_as_warnings(mi)
    if getattr(mi, "__version__", "") != PACKAGE_VERSION:
        raise RuntimeError(f"mitsuba {PACKAGE_VERSION} is required, found {getattr(mi, '__version__', '?')}")
    problems = []
    for variant in VARIANTS:
        if variant not in mi.variants():
            problems.append(f"{variant}: not built")
            continue
        if variant.startswith("llvm"):
            from minirt.jit.engine import llvm_status

            ok, why = llvm_status()
            if not ok:
                problems.append(f"{variant}: {why}")
                continue
        try:
            mi.set_variant(variant)
            mi.load_dict({"type": "scene"})  # smoke test: a kernel-free load
        except Exception as e:  # a variant that cannot run is not fatal: try the next one
            problems.append(f"{variant}: {type(e).__name__}: {e}")
            continue
        _state.update(mi=mi, variant=variant, problems=problems)
        return mi, variant
    raise RuntimeError("no usable Mitsuba variant (" + "; ".join(problems) + ")")


_LOG_PREFIX = re.compile(r"^\s*\S+ \S+ +[A-Z]+ +")  # Mitsuba's "2026-12-07 04:36:55 WARN  " before the text


def _log_as_warnings(mi: Any) -> None:
    """Mitsuba's log records of level Warn and above as Python warnings ("Mitsuba: [Sphere] ..."),
    instead of its own lines (colour codes, a date) on standard output."""
    import warnings

    class _Warnings(mi.Appender):
        def append(self, level, text: str) -> None:
            if level >= mi.LogLevel.Warn:
                said = " ".join(_LOG_PREFIX.sub("", re.sub(r"\x1b\[[0-9;]*m", "", text)).split())
                with contextlib.suppress(Exception):  # -W error: raised into Mitsuba's C++, it would abort
                    warnings.warn(f"Mitsuba: {said}", RuntimeWarning, stacklevel=1)

        def log_progress(self, *args) -> None:  # no progress bars of Mitsuba's own
            pass

    logger = mi.logger()
    logger.clear_appenders()
    logger.add_appender(_Warnings())


def one_line(e: BaseException) -> str:
    """An exception as one line of at most 300 characters, its type first: the reason a skipped or
    failed Mitsuba render gives (the oracle's ``available`` and ``render``)."""
    text = f"{type(e).__name__}: {e}".strip()
    return " ".join(text.split())[:300]
