"""Job results stored by content hash, so a rerun does only the jobs whose inputs changed.

A job's key is the SHA-256 of everything its result depends on: what the job carries (a scene's text,
the backend, the settings) and the versions of the code that computes it -- a digest of minirt's own
sources (``code_digest``), Dr.Jit's version and each oracle's version line (``versions``). The result is
stored as ``FOLDER/KEY.EXT``. Only the process that runs the command reads and writes the folder
(minirt.jobs.batch hands results back to it), so Dask workers need no shared file system.

**Entries are data, never code.** Two codecs: ``json_codec`` for results that are plain JSON (the
campaign's), and ``data_codec(schema)`` for results with arrays and dataclasses (a check's renders and
figures, a class's rows, a sweep's series): JSON for the structure and NumPy's ``.npy`` for the arrays,
read with ``allow_pickle=False`` (minirt.jobs.data). Reading an entry never runs code, whoever wrote it.

**A cache folder is still input.** Whoever can write it decides what a rerun reports, so by default it
must be this user's alone: owned by the effective user, not writable by others, and writable by its group
only when that group is the user's own private group (named after the user, as Debian and Ubuntu make
them). Anything else is one line and exit status 2 before any work -- unless ``MINIRT_CACHE_SHARED=1``
says the folder is shared on purpose (a course's folder, a cluster's disk) and its writers are trusted
with the results. Either way:

- an entry is read only if it is a regular file (never a FIFO, a device or a symbolic link, which are not
  even opened), owned by this user unless shared, and at most ``max_bytes`` long;
- an entry must start with its own key, decode, and pass its schema's check and the cache's ``accept``;
  one that does not (truncated, stale, foreign, of the wrong shape) is recomputed and replaced;
- an entry that is a folder cannot be replaced: one line naming it, before any work.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from minirt.jobs.data import Schema

MAGIC = b"minirt-cache 1\n"
MAX_ENTRY_BYTES = 4 << 30  # an entry larger than this is not read (nor stored): a 1024² check is ~0.3 GB
SHARED = "MINIRT_CACHE_SHARED"  # =1: the folder is shared on purpose; its writers are trusted with results


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


def _no_check(result: Any) -> None:
    return None


@dataclass(frozen=True)
class Codec:
    """How results are written (``encode``) and read back (``decode``: raises on anything it did not
    write); ``check`` raises ValueError for a result of the wrong shape (minirt.jobs.data.Schema.check)."""

    ext: str
    encode: Callable[[Any], bytes]
    decode: Callable[[bytes], Any]
    check: Callable[[Any], None] = _no_check


def _json_encode(result: Any) -> bytes:
    return json.dumps(result, sort_keys=True, allow_nan=False).encode()


json_codec = Codec("json", _json_encode, lambda b: json.loads(b.decode()))


def data_codec(schema: Schema) -> Codec:
    """Results of ``schema``'s type as data (minirt.jobs.data): JSON and .npy, checked when read."""
    return Codec("data", schema.encode, schema.decode, schema.check)


def shared() -> bool:
    """Whether the user said the cache folder is shared on purpose (``MINIRT_CACHE_SHARED=1``)."""
    return os.environ.get(SHARED, "").strip().lower() in ("1", "true", "yes")


def _private_group(gid: int, uid: int) -> bool:
    """Whether ``gid`` is ``uid``'s own group: its primary group, named after it (a user private group)."""
    import grp
    import pwd

    try:
        user = pwd.getpwuid(uid)
        return user.pw_gid == gid and grp.getgrgid(gid).gr_name == user.pw_name
    except KeyError:
        return False


def _owner(uid: int) -> str:
    import pwd

    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return f"uid {uid}"


def trusted_folder(folder: Path, label: str = "--cache") -> None:
    """Raise MinirtError (one line) unless ``folder`` -- when it exists -- is this user's alone (the
    module's docstring), or the user said it is shared (``MINIRT_CACHE_SHARED=1``)."""
    from minirt.errors import MinirtError

    try:
        st = folder.stat()
    except FileNotFoundError:
        return
    except OSError as e:
        raise MinirtError(f"{label} {folder}: cannot use the folder ({e.strerror or e})") from None
    if not stat.S_ISDIR(st.st_mode):
        raise MinirtError(f"{label} {folder}: not a folder")
    if shared():
        return
    me = os.geteuid()
    why = ""
    if st.st_uid != me:
        why = f"it belongs to {_owner(st.st_uid)}"
    elif st.st_mode & stat.S_IWOTH:
        why = "everyone may write in it"
    elif st.st_mode & stat.S_IWGRP and not _private_group(st.st_gid, me):
        import grp

        try:
            group = grp.getgrgid(st.st_gid).gr_name
        except KeyError:
            group = f"gid {st.st_gid}"
        why = f"its group {group} may write in it"
    if why:
        raise MinirtError(
            f"{label} {folder}: {why}, and whoever writes a cache decides what a rerun reports; use a folder "
            f"of your own, or set {SHARED}=1 if you trust everyone who can write there"
        )


@dataclass
class Cache:
    """A folder of job results. ``key(item)``: the item's content hash; ``keep(result)``: whether a result
    may be stored (not an error that a dead worker or a missing renderer could have caused);
    ``accept(item, result)``: on a hit, whether the stored result can stand (and restore what it needs,
    such as a page it wrote) -- false, or an exception, and the item is run again. ``label``: how messages
    name the folder (the option that gave it). The folder is checked when the cache is made
    (``trusted_folder``); ``max_bytes``: the largest entry read or written."""

    folder: Path
    key: Callable[[Any], str]
    codec: Codec = json_codec
    keep: Callable[[Any], bool] = lambda result: True
    accept: Callable[[Any, Any], bool] = lambda item, result: True
    label: str = "--cache"
    max_bytes: int = MAX_ENTRY_BYTES
    hits: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        trusted_folder(self.folder, self.label)

    def _path(self, key: str) -> Path:
        return self.folder / f"{key}.{self.codec.ext}"

    def _read(self, path: Path) -> bytes | None:
        """The entry's bytes, or None when there is none or it may not be read (the module's docstring).
        Nothing but a regular file is opened: a FIFO would block, a device (or a link to one) never ends."""
        from minirt.errors import MinirtError

        try:
            st = path.lstat()
        except OSError:
            return None
        if stat.S_ISDIR(st.st_mode):
            raise MinirtError(
                f"{self.label} {self.folder}: the entry {path.name} is a folder, not a file minirt wrote; remove it"
            )
        if not stat.S_ISREG(st.st_mode) or st.st_size > self.max_bytes:
            return None
        if st.st_uid != os.geteuid() and not shared():
            return None
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError as e:
            if e.errno not in (errno.ENOENT, errno.ELOOP, errno.EACCES, errno.EPERM):
                raise
            return None
        with contextlib.closing(os.fdopen(fd, "rb")) as f:
            now = os.fstat(f.fileno())
            if not stat.S_ISREG(now.st_mode) or (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
                return None  # replaced between the look and the open
            data = f.read(self.max_bytes + 1)
        return None if len(data) > self.max_bytes else data

    def load(self, item: Any) -> Any | None:
        """The stored result of ``item``, or None (none stored, unreadable, not this key's, or not of the
        codec's shape). MinirtError for an entry that is a folder: it could never be replaced."""
        key = self.key(item)
        data = self._read(self._path(key))
        if data is None:
            return None
        head = MAGIC + key.encode() + b"\n"
        if not data.startswith(head):
            return None
        try:
            result = self.codec.decode(data[len(head) :])
            self.codec.check(result)
            if not self.accept(item, result):
                return None
        except Exception:  # a truncated, foreign or crafted entry: recompute it
            return None
        self.hits += 1
        return result

    def store(self, item: Any, result: Any) -> None:
        if not self.keep(result):
            return
        from minirt.io.atomic import atomic_path

        key = self.key(item)
        data = MAGIC + key.encode() + b"\n" + self.codec.encode(result)
        if len(data) > self.max_bytes:
            return  # it could not be read back
        self.folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        with atomic_path(self._path(key)) as tmp:
            tmp.write_bytes(data)
