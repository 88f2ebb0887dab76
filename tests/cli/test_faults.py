"""Faulty renderers and signals: a fake `povray` on PATH that crashes, hangs, talks garbage or writes
broken files; SIGTERM and SIGINT in the middle of a render. The other backends always finish, the
verdict names the fault in words, nothing is left behind (temporary files, folders, child processes).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from support.inproc import minirt

FAKE = r"""#!/bin/sh
# a fake povray: $FAKE_MODE says how it misbehaves
if [ "$1" = "--version" ]; then
  case "$FAKE_MODE" in
    version-hang) sleep 600 ;;
    version-garbage) printf '\377\376 not a version \033[2J\n'; exit 0 ;;
  esac
  echo "POV-Ray 3.7.0.10.unofficial"; exit 0
fi
case "$FAKE_MODE" in
  crash) echo "Parse Error: [/] [link=file:///etc/passwd]x[/link] $(printf '\033]0;owned\007')" >&2; exit 1 ;;
  segv) kill -SEGV $$ ;;
  hang) echo $$ >> "$FAKE_PIDS"; sleep 600 ;;
  garbage) for i in 1 2 3 4 5 6 7; do printf 'garbage' > out$i.exr; printf 'garbage' > out$i.png; done; exit 0 ;;
  nothing) exit 0 ;;
  startup|startup-once)
    # POV-Ray's start-up race (vfeInitializeTimedOut): every time, or on the first run only
    if [ "$FAKE_MODE" = startup ] || [ ! -e "$FAKE_PIDS.started" ]; then
      touch "$FAKE_PIDS.started"; echo "POV-Ray: Timed out waiting for worker thread startup" >&2; exit 1
    fi
    exec "$REAL_POVRAY" "$@" ;;
  truncated|wrong-size)
    # a real 4x4 (or 8x9) render by the real povray, then cut short
    size="+W8 +H8"; [ "$FAKE_MODE" = wrong-size ] && size="+W4 +H4"
    "$REAL_POVRAY" "$@" $size >/dev/null 2>&1 || exit 9
    if [ "$FAKE_MODE" = truncated ]; then for f in out*.exr out*.png; do head -c 200 "$f" > t && mv t "$f"; done; fi
    exit 0 ;;
esac
exit 3
"""


@pytest.fixture
def fake_povray(tmp_path, monkeypatch):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    exe = bin_dir / "povray"
    exe.write_text(FAKE)
    exe.chmod(0o755)
    monkeypatch.setenv("REAL_POVRAY", shutil.which("povray"))  # before the fake one shadows it
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_PIDS", str(tmp_path / "pids"))

    def mode(m: str) -> dict[str, str]:
        return {**os.environ, "FAKE_MODE": m}

    return mode


def _pov_temp(pid: int) -> list[Path]:
    """The temporary folders run ``pid`` made (others may be running minirt beside the tests)."""
    return list(Path(tempfile.gettempdir()).glob(f"minirt-povray-{pid}-*"))


@pytest.mark.parametrize(
    "mode, words",
    [
        ("crash", "Parse Error"),
        ("segv", "crashed (signal 11)"),
        ("garbage", "out1.exr"),
        ("nothing", "wrote no output"),
        ("version-garbage", "does not say it is POV-Ray"),
        ("truncated", "POV-Ray wrote a truncated or corrupt out1.exr"),
        ("wrong-size", "out1.exr at 4x4, not the 8x8 asked for"),
    ],
)
def test_a_faulty_povray_does_not_stop_the_others(fake_povray, tmp_path, monkeypatch, mode, words):
    monkeypatch.setenv("FAKE_MODE", mode)  # the fake povray is first on this process's PATH (fake_povray)
    p = minirt(
        "render", "exercise", "--backend", "reference,povray,embree", "--out", "out", "--width", "8", "--height", "8",
        cwd=tmp_path,
    )  # fmt: skip
    pid = os.getpid()  # the command ran in this process (tests/support/inproc.py): its temporary folders carry this pid
    text = p.stdout + p.stderr
    assert p.returncode == 0, text  # the reference and Embree rendered
    assert "Traceback" not in text and "MarkupError" not in text
    assert "\x1b" not in text and "\x07" not in text
    assert words in text
    files = sorted(q.name for q in (tmp_path / "out").iterdir())
    assert "exercise.reference.png" in files and "exercise.embree.json" in files
    assert not any(n.startswith(".") for n in files)
    assert _pov_temp(pid) == []  # no temporary folder of this run left


def test_a_hanging_povray_times_out_and_is_killed(fake_povray, tmp_path, monkeypatch):
    from minirt.harness import backends
    from minirt.model.bundled import bundled_scene
    from minirt.model.rules import resolve

    monkeypatch.setenv("FAKE_MODE", "hang")
    scene = bundled_scene("exercise").with_overrides(width=8, height=8)
    t0 = time.perf_counter()
    pov = backends.get("povray")
    res = pov.render(scene, pov.adapt(resolve(scene)), {"timeout": 1.5})
    assert time.perf_counter() - t0 < 20
    assert res.status == "error" and "timed out after 1.5 s" in res.reason, res.reason
    for pid in (tmp_path / "pids").read_text().split():
        with pytest.raises(ProcessLookupError):  # killed with its process group, not orphaned
            for _ in range(50):
                os.kill(int(pid), 0)
                time.sleep(0.1)


def test_povrays_startup_race_is_run_again_and_said_when_it_stays(fake_povray, tmp_path, monkeypatch):
    """POV-Ray's "Timed out waiting for worker thread startup" (a loaded machine) is retried; a pass that keeps
    failing so is an ERROR that says it."""
    from minirt.harness import backends
    from minirt.model.bundled import bundled_scene
    from minirt.model.rules import resolve

    scene = bundled_scene("exercise").with_overrides(width=8, height=8)
    pov = backends.get("povray")
    monkeypatch.setenv("FAKE_MODE", "startup-once")
    res = pov.render(scene, pov.adapt(resolve(scene)), {})
    assert res.ok, res.reason
    assert (tmp_path / "pids.started").exists()  # the first run did fail
    monkeypatch.setenv("FAKE_MODE", "startup")
    res = pov.render(scene, pov.adapt(resolve(scene)), {})
    assert res.status == "error" and "worker thread startup" in res.reason, res.reason


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_cleans_up(fake_povray, tmp_path, sig):
    """minirt stopped mid-render (POV-Ray hanging in its two passes): exit 128+N within seconds, no
    temporary file in --out, no temporary folder, no povray left running."""
    env = fake_povray("hang")
    p = subprocess.Popen(
        [sys.executable, "-m", "minirt", "render", "exercise", "--backend", "reference,povray", "--out", "out",
         "--width", "8", "--height", "8"], cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    pids = tmp_path / "pids"
    written = tmp_path / "out" / "exercise.reference.json"
    # Until POV-Ray's passes are running and the reference's files are written: minirt then waits for
    # POV-Ray alone. (Before that the signal may land in a Dr.Jit kernel compile, which Python cannot
    # interrupt: with an empty kernel cache on a loaded runner that took over 30 s once.)
    for _ in range(1200):
        if pids.exists() and len(pids.read_text().split()) >= 2 and written.exists():
            break
        time.sleep(0.1)
    else:
        p.kill()
        pytest.fail("the fake povray never started, or the reference was never written")
    p.send_signal(sig)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 128 + sig, err
    assert b"Traceback" not in err
    assert not [q for q in (tmp_path / "out").iterdir() if q.name.startswith(".")]
    assert _pov_temp(p.pid) == []
    for pid in pids.read_text().split():
        with pytest.raises(ProcessLookupError):
            for _ in range(50):
                os.kill(int(pid), 0)
                time.sleep(0.1)


def test_stale_temporaries_are_swept(tmp_path):
    """What a SIGKILLed run leaves (its pid is gone) is removed by the next run; a live run's is kept."""
    from minirt.io.atomic import TEMP_FILE, stale
    from minirt.io.images import write_image

    dead = subprocess.Popen(["true"])
    dead.wait()
    left = tmp_path / f".img.tmp{dead.pid}-abcd.png"
    left.write_bytes(b"")
    alive = tmp_path / f".img.tmp{os.getpid()}-efgh.png"
    alive.write_bytes(b"")
    assert stale(tmp_path, TEMP_FILE) == [left]
    import numpy as np

    write_image(tmp_path / "img.png", np.zeros((2, 2, 3), np.uint8))
    assert not left.exists() and alive.exists()


def test_render_timeout_option(fake_povray, tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_MODE", "hang")
    p = minirt(
        "render", "exercise", "--backend", "povray", "--timeout", "1", "--width", "8", "--height", "8",
        "--out", "out", cwd=tmp_path,
    )  # fmt: skip
    assert p.returncode == 2  # no backend rendered
    assert "POV-Ray timed out after 1 s" in p.stderr and "Traceback" not in p.stderr
