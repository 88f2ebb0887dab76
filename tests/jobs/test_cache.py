"""minirt.jobs.cache and minirt.jobs.batch's use of it: a result is reused only under its own key, intact,
of the right shape -- and a cache folder is input like any other: a crafted entry never runs code, an
entry that is not a regular file is never opened, and a folder someone else can write is refused."""

from __future__ import annotations

import os
import pickle
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from support.inproc import minirt

from minirt.errors import MinirtError
from minirt.jobs import batch as jobs
from minirt.jobs.cache import MAGIC, SHARED, Cache, data_codec, digest, json_codec
from minirt.jobs.data import Schema

CALLS: list[int] = []


def square(x: int) -> dict:
    CALLS.append(x)
    return {"x": x, "y": x * x}


@dataclass
class Part:
    name: str
    values: np.ndarray
    extra: dict[str, float] = field(default_factory=dict)


PARTS = Schema(tuple[Part, Part | None], (Part,))


def part(x: int) -> tuple[Part, Part | None]:
    CALLS.append(x)
    return Part(f"p{x}", np.arange(x, dtype=np.float32), {"nan": float("nan")}), None


def key(x) -> str:
    return digest({"x": x})


def entry(folder: Path, item, ext: str = "data") -> Path:
    return folder / f"{key(item)}.{ext}"


@pytest.fixture
def folder(tmp_path) -> Path:
    d = tmp_path / "cache"
    d.mkdir(mode=0o700)
    return d


def test_jobs_run_takes_stored_results_and_stores_new_ones(folder):
    cache = Cache(folder, key=key, codec=json_codec)
    CALLS.clear()
    assert jobs.run(square, [1, 2, 3], cache=cache) == [square(1), square(2), square(3)]
    CALLS.clear()
    again = Cache(folder, key=key, codec=json_codec)
    assert jobs.run(square, [3, 4, 1], cache=again) == [{"x": 3, "y": 9}, {"x": 4, "y": 16}, {"x": 1, "y": 1}]
    assert CALLS == [4] and again.hits == 2


def test_an_entry_is_used_only_under_its_own_key_and_intact(folder):
    cache = Cache(folder, key=key, codec=data_codec(PARTS))
    cache.store(1, part(1))
    (e,) = folder.iterdir()
    got = cache.load(1)
    assert got[0].name == "p1" and got[0].values.dtype == np.float32 and np.isnan(got[0].extra["nan"])
    assert cache.load(2) is None
    e.rename(entry(folder, 2))  # an entry copied to another key's name is not that key's result
    assert cache.load(2) is None
    cache.store(3, part(3))
    p = entry(folder, 3)
    p.write_bytes(p.read_bytes()[:-3])  # truncated
    assert cache.load(3) is None


def test_results_the_cache_must_not_keep_are_not_stored(folder):
    cache = Cache(folder, key=key, keep=lambda r: r["y"] != 4)
    jobs.run(square, [1, 2], cache=cache)
    assert cache.load(1) == {"x": 1, "y": 1} and cache.load(2) is None
    assert not list(folder.glob("*.tmp*"))


def test_the_python_api_check_takes_a_cache(folder):
    """minirt.check(cache=DIR): the second call takes its result from DIR (the first call's seconds)."""
    import minirt

    first = minirt.check("exercise", backends=["embree"], size=(16, 16), cache=folder)
    again = minirt.check("exercise", backends=["embree"], size=(16, 16), cache=folder)
    a, b = first.scenes[0].backends["embree"], again.scenes[0].backends["embree"]
    assert a.verdict == b.verdict == "pass" and a.seconds == b.seconds and len(list(folder.iterdir())) == 1
    (e,) = folder.iterdir()
    assert e.suffix == ".data" and MAGIC in e.read_bytes()[:20]


# ---- crafted entries ----------------------------------------------------------------------------


class Bomb:
    """Loading a pickle of this creates the file MARK: the proof that loading ran code."""

    mark = ""

    def __reduce__(self):
        return (open, (self.mark, "w"))


def bomb_pickle(mark: Path) -> bytes:
    Bomb.mark = str(mark)
    return pickle.dumps(Bomb())


def bomb_npy(mark: Path) -> bytes:
    """A .npy of dtype object whose element is a Bomb: numpy unpickles it if allowed to."""
    import io

    Bomb.mark = str(mark)
    a = np.empty(1, dtype=object)
    a[0] = Bomb()
    f = io.BytesIO()
    np.lib.format.write_array(f, a, allow_pickle=True)
    return f.getvalue()


def crafted(item, body: bytes) -> bytes:
    return MAGIC + key(item).encode() + b"\n" + body


def test_a_crafted_entry_never_runs_code_and_is_recomputed(folder, tmp_path):
    """Entries with the right name and header: a pickle (the old format), a .npy of Python objects behind
    a valid structure line, and the same array where a scalar is expected. None runs code; each is
    recomputed and replaced by an entry minirt wrote."""
    mark = tmp_path / "ran"
    cache = Cache(folder, key=key, codec=data_codec(PARTS))
    head = b'{"arrays":1,"value":{"$t":[{"$c":"Part","f":{"name":"p","values":{"$a":0},"extra":{"$d":[]}}},null]}}\n'
    bodies = {
        1: bomb_pickle(mark),
        2: head + bomb_npy(mark),
        3: head.replace(b'"$a":0', b'"$n":0') + bomb_npy(mark),
    }
    for item, body in bodies.items():
        entry(folder, item).write_bytes(crafted(item, body))
        entry(folder, item, "pickle").write_bytes(crafted(item, bomb_pickle(mark)))
    CALLS.clear()
    got = jobs.run(part, [1, 2, 3], cache=cache)
    assert not mark.exists(), "loading an entry ran code"
    assert CALLS == [1, 2, 3] and cache.hits == 0 and [g[0].name for g in got] == ["p1", "p2", "p3"]
    again = Cache(folder, key=key, codec=data_codec(PARTS))
    assert [again.load(i)[0].name for i in (1, 2, 3)] == ["p1", "p2", "p3"]  # replaced by minirt's own entries


def test_a_decoded_entry_of_the_wrong_shape_is_recomputed(folder):
    """The right header and a payload minirt could have written, but not of the result's type: a dict for
    the tuple, a Part whose name is a number, an unknown class, an array of Python objects' dtype name."""
    cache = Cache(folder, key=key, codec=data_codec(PARTS))
    wrong = {
        1: b'{"arrays":0,"value":{"$d":[["x",1]]}}\n',
        2: b'{"arrays":0,"value":{"$t":[{"$c":"Part","f":{"name":5,"values":null,"extra":{"$d":[]}}},null]}}\n',
        3: b'{"arrays":0,"value":{"$t":[{"$c":"Path","f":{}},null]}}\n',
        4: b'{"arrays":0,"value":{"$t":[{"$c":"Part","f":{"name":"p"}},null]}}\n',
        5: b'{"arrays":2,"value":null}\n',
    }
    for item, body in wrong.items():
        entry(folder, item).write_bytes(crafted(item, body))
        assert cache.load(item) is None, item
    CALLS.clear()
    jobs.run(part, list(wrong), cache=cache)
    assert list(wrong) == CALLS


@pytest.mark.parametrize("kind", ["fifo", "link to /dev/zero", "link to a good entry", "oversized"])
def test_an_entry_that_is_not_a_small_regular_file_is_never_read(folder, kind):
    """A FIFO would block the read forever and /dev/zero never ends: neither is opened. A link is not
    followed, even to an entry minirt wrote. A file over the cap is not read. Each is recomputed and
    replaced by a regular file."""
    cache = Cache(folder, key=key, codec=data_codec(PARTS), max_bytes=4096)
    p = entry(folder, 5)
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "link to /dev/zero":
        p.symlink_to("/dev/zero")
    elif kind == "link to a good entry":
        cache.store(6, part(5))
        p.symlink_to(entry(folder, 6))
    else:
        cache.store(5, (Part("big", np.zeros(1024)), None))  # 8 KiB of array: over the cap, so not stored
        assert not p.exists()
        p.write_bytes(crafted(5, b"x" * 8192))
    t0 = time.monotonic()
    assert cache.load(5) is None
    CALLS.clear()
    got = jobs.run(part, [5], cache=cache)
    assert time.monotonic() - t0 < 10 and CALLS == [5] and got[0][0].name == "p5"
    assert stat.S_ISREG(p.lstat().st_mode) and cache.load(5)[0].name == "p5"


def test_an_entry_that_is_a_folder_is_one_line_naming_it(folder):
    cache = Cache(folder, key=key, codec=data_codec(PARTS))
    entry(folder, 7).mkdir()
    with pytest.raises(MinirtError, match=rf"--cache {folder}: the entry {key(7)}\.data is a folder"):
        jobs.run(part, [7], cache=cache)


# ---- the folder ---------------------------------------------------------------------------------


def test_a_folder_others_can_write_is_refused_unless_shared(folder, monkeypatch):
    folder.chmod(0o777)
    with pytest.raises(MinirtError, match=r"everyone may write in it.*MINIRT_CACHE_SHARED=1"):
        Cache(folder, key=key)
    monkeypatch.setenv(SHARED, "1")
    Cache(folder, key=key).store(1, {"y": 1})
    assert Cache(folder, key=key).load(1) == {"y": 1}


def test_a_folder_of_someone_else_is_refused_unless_shared(folder, monkeypatch):
    """As another user sees it (the effective user id differs from the owner's): the folder is refused,
    and in a shared folder only the entries of the user running minirt would be used without it."""
    Cache(folder, key=key).store(1, {"y": 1})
    me = os.geteuid()
    monkeypatch.setattr(os, "geteuid", lambda: me + 1)
    with pytest.raises(MinirtError, match=r"it belongs to"):
        Cache(folder, key=key)
    monkeypatch.setenv(SHARED, "yes")
    assert Cache(folder, key=key).load(1) == {"y": 1}  # shared on purpose: its writers are trusted
    monkeypatch.delenv(SHARED)
    monkeypatch.setattr(os, "geteuid", lambda: me)
    assert Cache(folder, key=key).load(1) == {"y": 1}


def test_a_missing_folder_is_made_for_its_owner_alone(tmp_path):
    cache = Cache(tmp_path / "new", key=key)
    cache.store(1, {"y": 1})
    assert stat.S_IMODE((tmp_path / "new").stat().st_mode) & 0o077 == 0


# ---- the command line ---------------------------------------------------------------------------


def test_check_with_a_crafted_cache_runs_no_code_and_prints_the_same(tmp_path):
    """`minirt check --cache DIR`: every entry of a first run replaced by a pickle that would create a file
    when loaded, and by a .npy of Python objects -- the second run creates nothing, checks again and
    writes the same document (its seconds aside)."""
    cache, mark = tmp_path / "cache", tmp_path / "ran"
    args = ["check", "exercise", "--size", "16x16", "-b", "embree", "-q", "--cache", cache]
    first = minirt(*args, "--json", tmp_path / "1.json")
    assert first.returncode == 0, first.stderr
    (e,) = cache.iterdir()
    header = e.read_bytes().split(b"\n", 2)
    for body in (bomb_pickle(mark), b'{"arrays":1,"value":{"$a":0}}\n' + bomb_npy(mark)):
        e.write_bytes(header[0] + b"\n" + header[1] + b"\n" + body)
        again = minirt(*args, "--json", tmp_path / "2.json")
        assert again.returncode == 0 and "Traceback" not in again.stderr and "error" not in again.stderr
        assert not mark.exists()
        assert b'"$c":"BackendCheck"' in e.read_bytes()  # checked again, and the entry written anew
        a, b = ((tmp_path / f"{n}.json").read_text() for n in (1, 2))
        assert _without_seconds(a) == _without_seconds(b)


def _without_seconds(text: str) -> str:
    import json

    def strip(o):
        if isinstance(o, dict):
            return {k: strip(v) for k, v in o.items() if "seconds" not in k}
        return [strip(v) for v in o] if isinstance(o, list) else o

    return json.dumps(strip(json.loads(text)), sort_keys=True)


@pytest.mark.parametrize(
    "how, words",
    [
        ("writable by all", "everyone may write in it"),
        ("entry is a folder", "is a folder, not a file minirt wrote; remove it"),
        ("not a folder", "cannot create the folder"),
    ],
)
def test_a_bad_cache_folder_is_one_line_and_exit_2(tmp_path, how, words):
    cache = tmp_path / "cache"
    if how == "not a folder":
        cache.write_text("x")
    else:
        cache.mkdir()
    if how == "writable by all":
        cache.chmod(0o777)
    p = minirt("check", "exercise", "--size", "8x8", "-b", "embree", "-q", "--cache", cache)
    if how == "entry is a folder":  # a first run's entry, turned into a folder
        assert p.returncode == 0, p.stderr
        (e,) = cache.iterdir()
        e.unlink()
        e.mkdir()
        p = minirt("check", "exercise", "--size", "8x8", "-b", "embree", "-q", "--cache", cache)
        words = f"{e.name} {words}"
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    (line,) = p.stderr.splitlines()
    assert line.startswith(f"minirt: error: --cache {cache}") and words in line, line


def test_a_check_entry_of_the_wrong_size_is_recomputed(tmp_path):
    """An entry of the right types under a check's key, but holding an 8x8 check of the 16x16 job: the
    arrays do not fit the scene, so it is checked again (a report of mixed sizes would break)."""
    import minirt

    small, big = tmp_path / "small", tmp_path / "big"
    minirt.check("exercise", backends=["embree"], size=(8, 8), cache=small)
    minirt.check("exercise", backends=["embree"], size=(16, 16), cache=big)
    ((s,), (b,)) = (list(small.iterdir()), list(big.iterdir()))
    head = b.read_bytes().split(b"\n", 2)[:2]
    b.write_bytes(b"\n".join([*head, s.read_bytes().split(b"\n", 2)[2]]))
    again = minirt.check("exercise", backends=["embree"], size=(16, 16), cache=big)
    assert again.scenes[0].reference.width == 16 and again.scenes[0].backends["embree"].result.width == 16
    assert b.read_bytes().split(b"\n", 2)[2] != s.read_bytes().split(b"\n", 2)[2]  # written again


def test_a_class_row_from_the_cache_never_writes_outside_out(tmp_path):
    """A class's cached row names the page its bytes are written back to: an entry whose page points
    elsewhere ("../../evil.html") is not used -- the image is graded again, nothing lands outside --out."""
    from minirt.grading.grade import ClassRow

    scenes, klass, out, cache = (tmp_path / n for n in ("scenes", "class", "out", "cache"))
    scenes.mkdir()
    lines = (Path(__file__).resolve().parents[2] / "scenes" / "exercise.toml").read_text().splitlines()
    lines = [ln for ln in lines if ln.split("=")[0].strip() not in ("width", "height", "samples")]
    (scenes / "exercise.toml").write_text("\n".join(lines).replace("[camera]", "[camera]\nwidth = 16\nheight = 16", 1))
    assert minirt("render", scenes / "exercise.toml", "--out", tmp_path / "r", "-q").returncode == 0
    (klass / "ann").mkdir(parents=True)
    (klass / "ann" / "exercise.png").write_bytes((tmp_path / "r" / "exercise.reference.png").read_bytes())
    args = ["grade", "--class", klass, "--scenes", scenes, "--out", out, "--cache", cache, "--workers", "1"]
    assert "(0 of 1 from the cache)" in minirt(*args).stdout
    (e,) = cache.iterdir()
    head, body = e.read_bytes().split(b"\n", 2)[:2], e.read_bytes().split(b"\n", 2)[2]
    codec = data_codec(Schema(ClassRow, (ClassRow,)))
    row = codec.decode(body)
    assert row.page == "pages/ann-exercise.html" and row.page_html
    row.page = "../../evil.html"
    e.write_bytes(b"\n".join([*head, codec.encode(row)]))
    p = minirt(*args)
    assert p.returncode == 0 and "(0 of 1 from the cache)" in p.stdout, p.stdout + p.stderr
    assert not (tmp_path / "evil.html").exists() and not (out.parent.parent / "evil.html").exists()


# ---- the format, over generated values and bytes ------------------------------------------------

ARRAYS = hnp.arrays(
    dtype=st.sampled_from([np.float64, np.float32, np.int32, np.uint8, np.bool_]),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, max_side=4),
)
LEAVES = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20) | st.binary(max_size=20)
VALUES = st.recursive(
    LEAVES | ARRAYS,
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.tuples(inner, inner)
        | st.dictionaries(st.text(max_size=8) | st.integers(), inner, max_size=4)
    ),
    max_leaves=20,
)
ANY = Schema(object)


def same(a, b) -> bool:
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    if isinstance(a, float):
        return type(b) is float and (a == b or (a != a and b != b))
    if isinstance(a, dict):
        return type(b) is dict and list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(VALUES)
def test_what_is_written_is_read_back_exactly(value):
    """Types included: a tuple stays a tuple, an int key an int, NaN and infinities, every array's dtype."""
    assert same(value, ANY.decode(ANY.encode(value)))


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(VALUES, st.data())
def test_damaged_bytes_are_refused_or_read_as_data(value, data):
    """An entry's bytes, cut short or with bytes changed: reading raises or gives data of the schema --
    nothing else happens (the schema makes no class; a wrong one is refused by the cache's check)."""
    raw = bytearray(PARTS.encode((Part("p", np.arange(3.0), {"a": 1.0}), None)) + ANY.encode(value))
    for _ in range(data.draw(st.integers(1, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(raw)))
    for body in (bytes(raw), bytes(raw[:cut])):
        try:
            got = PARTS.decode(body)
        except Exception:
            continue
        assert isinstance(got, tuple) and isinstance(got[0], Part)
