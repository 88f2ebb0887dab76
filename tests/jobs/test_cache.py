"""minirt.jobs.cache and minirt.jobs.batch' use of it: a result is reused only under its own key, intact."""

from __future__ import annotations

from minirt.jobs import batch as jobs
from minirt.jobs.cache import Cache, digest, json_codec, pickle_codec

CALLS: list[int] = []


def square(x: int) -> dict:
    CALLS.append(x)
    return {"x": x, "y": x * x}


def test_jobs_run_takes_stored_results_and_stores_new_ones(tmp_path):
    cache = Cache(tmp_path, key=lambda x: digest({"x": x}), codec=json_codec)
    CALLS.clear()
    assert jobs.run(square, [1, 2, 3], cache=cache) == [square(1), square(2), square(3)]
    CALLS.clear()
    again = Cache(tmp_path, key=lambda x: digest({"x": x}), codec=json_codec)
    assert jobs.run(square, [3, 4, 1], cache=again) == [{"x": 3, "y": 9}, {"x": 4, "y": 16}, {"x": 1, "y": 1}]
    assert CALLS == [4] and again.hits == 2


def test_an_entry_is_used_only_under_its_own_key_and_intact(tmp_path):
    cache = Cache(tmp_path, key=lambda x: digest({"x": x}), codec=pickle_codec)
    cache.store(1, {"y": 1})
    (entry,) = tmp_path.iterdir()
    assert cache.load(1) == {"y": 1} and cache.load(2) is None
    # an entry copied to another key's name is not that key's result
    entry.rename(tmp_path / f"{digest({'x': 2})}.pickle")
    assert cache.load(2) is None
    cache.store(3, {"y": 9})
    p = tmp_path / f"{digest({'x': 3})}.pickle"
    p.write_bytes(p.read_bytes()[:-3])  # truncated
    assert cache.load(3) is None


def test_results_the_cache_must_not_keep_are_not_stored(tmp_path):
    cache = Cache(tmp_path, key=lambda x: digest({"x": x}), keep=lambda r: r["y"] != 4)
    jobs.run(square, [1, 2], cache=cache)
    assert cache.load(1) == {"x": 1, "y": 1} and cache.load(2) is None
    assert not list(tmp_path.glob("*.tmp*"))


def test_the_python_api_check_takes_a_cache(tmp_path):
    """minirt.check(cache=DIR): the second call takes its result from DIR (the first call's seconds)."""
    import minirt

    first = minirt.check("exercise", backends=["embree"], size=(16, 16), cache=tmp_path)
    again = minirt.check("exercise", backends=["embree"], size=(16, 16), cache=tmp_path)
    a, b = first.scenes[0].backends["embree"], again.scenes[0].backends["embree"]
    assert a.verdict == b.verdict == "pass" and a.seconds == b.seconds and len(list(tmp_path.iterdir())) == 1
