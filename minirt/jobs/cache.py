"""Job results stored by content hash, so a rerun does only the jobs whose inputs changed.

A job's key is the SHA-256 of everything its result depends on: what the job carries (a scene's text,
the backend, the settings) and the versions of the code that computes it -- a digest of minirt's own
sources (``code_digest``), Dr.Jit's version and each oracle's version line (``versions``). The result is
stored as ``FOLDER/KEY.EXT``. Only the process that runs the command reads and writes the folder
(minirt.jobs.batch hands results back to it), so Dask workers need no shared file system.

Two codecs: ``json_codec`` for results that are plain JSON (the campaign's), ``pickle_codec`` for
results with arrays and dataclasses (a check's renders and figures). A pickle runs code when loaded, so a
cache folder is as trusted as minirt's own code: like ``__pycache__``, it is only ever written by minirt,
into the folder the user names. Each entry starts with its own key, and an entry whose key does not match
its name, or that cannot be read, is recomputed -- a truncated or stale file is never used.
"""

from __future__ import annotations

import hashlib
import json
import pickle
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MAGIC = b"minirt-cache 1\n"


def digest(parts: dict[str, Any]) -> str:
    """SHA-256 of a JSON-able dict (keys sorted): a cache key."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def code_digest() -> str:
    """SHA-256 of minirt's and its oracles' sources: a result computed by other code is not reused.
    The folders are found, not imported: minirt.oracles is its own folder in a checkout (oracles/,
    pyproject.toml's package-dir) and inside minirt/ in a wheel."""
    import importlib.util

    package = Path(__file__).resolve().parents[1]
    spec = importlib.util.find_spec("minirt.oracles")
    roots = {package, *(Path(p).resolve() for p in (spec.submodule_search_locations or []))} if spec else {package}
    h = hashlib.sha256()
    for p in sorted({p for root in roots for p in root.rglob("*.py")}):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class Codec:
    ext: str
    encode: Callable[[Any], bytes]
    decode: Callable[[bytes], Any]


def _json_encode(result: Any) -> bytes:
    return json.dumps(result, sort_keys=True, allow_nan=False).encode()


json_codec = Codec("json", _json_encode, lambda b: json.loads(b.decode()))
pickle_codec = Codec("pickle", lambda r: pickle.dumps(r, protocol=pickle.HIGHEST_PROTOCOL), pickle.loads)


@dataclass
class Cache:
    """A folder of job results. ``key(item)``: the item's content hash; ``keep(result)``: whether a result
    may be stored (not an error that a dead worker or a missing renderer could have caused);
    ``accept(item, result)``: on a hit, whether the stored result can stand (and restore what it needs,
    such as a page it wrote), else the item is run again."""

    folder: Path
    key: Callable[[Any], str]
    codec: Codec = json_codec
    keep: Callable[[Any], bool] = lambda result: True
    accept: Callable[[Any, Any], bool] = lambda item, result: True
    hits: int = field(default=0, init=False)

    def _path(self, key: str) -> Path:
        return self.folder / f"{key}.{self.codec.ext}"

    def load(self, item: Any) -> Any | None:
        """The stored result of ``item``, or None (none stored, unreadable, or not this key's)."""
        key = self.key(item)
        try:
            data = self._path(key).read_bytes()
        except OSError:
            return None
        head = MAGIC + key.encode() + b"\n"
        if not data.startswith(head):
            return None
        try:
            result = self.codec.decode(data[len(head) :])
        except Exception:  # a truncated or foreign entry: recompute it
            return None
        if not self.accept(item, result):
            return None
        self.hits += 1
        return result

    def store(self, item: Any, result: Any) -> None:
        if not self.keep(result):
            return
        from minirt.io.atomic import atomic_path

        key = self.key(item)
        self.folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(self._path(key)) as tmp:
            tmp.write_bytes(MAGIC + key.encode() + b"\n" + self.codec.encode(result))
