"""minirt's pytest plugin: your scenes pass against every oracle, as tests in your own suite.

pytest loads it by itself once minirt is installed (the ``pytest11`` entry point ``minirt`` in
pyproject.toml; ``-p no:minirt`` turns it off). It offers:

- the fixture ``minirt_check``: ``minirt_check("scenes/my.toml")`` is
  ``minirt.testing.assert_scene_passes`` with the run's backends and size;
- scene files as tests: with the ini key ``minirt_scenes`` set to glob patterns relative to the
  rootdir (``minirt_scenes = ["scenes/*.toml"]`` in ``[tool.pytest.ini_options]``), every matching
  file that pytest visits (its folder among the test paths) becomes one test, ``scenes/my.toml::check``.

Backends and size: ``--minirt-backends LIST`` and ``--minirt-size WxH``, or the ini keys
``minirt_backends`` (default ``all``) and ``minirt_size`` (default: each scene's own size).
This module imports nothing heavy: the renderers load when a check runs.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("minirt", "minirt scene checks")
    group.addoption(
        "--minirt-backends",
        default=None,
        metavar="LIST",
        help="Backends the scene checks compare with: all, or a comma list (default: ini minirt_backends, all).",
    )
    group.addoption(
        "--minirt-size",
        default=None,
        metavar="WxH",
        help="Render the checked scenes at WxH (default: ini minirt_size, else each scene's own size).",
    )
    parser.addini(
        "minirt_backends", "Backends minirt's scene checks compare with (all, or a comma list).", default="all"
    )
    parser.addini("minirt_size", "Size minirt's scene checks render at (WxH; empty: the scene's own).", default="")
    parser.addini("minirt_scenes", "Glob patterns (from the rootdir) of scene files to collect as tests.", type="args")


def _settings(config: pytest.Config) -> tuple[str, str]:
    backends = config.getoption("minirt_backends") or config.getini("minirt_backends") or "all"
    size = config.getoption("minirt_size") or config.getini("minirt_size") or ""
    return backends, size


@pytest.fixture
def minirt_check(request: pytest.FixtureRequest) -> Callable[..., Any]:
    """``minirt_check(scene, backends=None, size=None, allow_skip=False)``: assert that the scene (a
    file, a bundled scene's name, a folder, or a list) passes against the backends; None: the run's
    --minirt-backends / --minirt-size. Returns the CheckResult."""
    from minirt.testing import assert_scene_passes

    run_backends, run_size = _settings(request.config)

    def check(scene, backends=None, size=None, allow_skip=False):
        __tracebackhide__ = True
        return assert_scene_passes(
            scene, backends or run_backends, size=size or run_size or None, allow_skip=allow_skip
        )

    return check


def _wanted(file_path: Path, config: pytest.Config) -> bool:
    """Whether ini minirt_scenes names the file (a .toml file under the rootdir)."""
    patterns = config.getini("minirt_scenes")
    if file_path.suffix != ".toml" or not patterns:
        return False
    try:
        rel = file_path.relative_to(config.rootpath)
    except ValueError:
        return False
    return any(rel.match(p) for p in patterns)  # PurePath.match: "scenes/*.toml" matches from the right


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Collector | None:
    if _wanted(file_path, parent.config):
        return SceneFile.from_parent(parent, path=file_path)
    return None


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector):
    """A folder's scene files that pytest itself passes over -- it collects only what is a file or a folder
    once links are followed, so a broken symbolic link, a FIFO or a device named ``*.toml`` would vanish
    from the run without a word -- are collected too: each is a test that fails with what is wrong."""
    report = yield
    if isinstance(collector, pytest.Directory) and report.passed and collector.config.getini("minirt_scenes"):
        report.result.extend(SceneFile.from_parent(collector, path=p) for p in _passed_over(collector))
    return report


def _passed_over(folder: pytest.Directory) -> list[Path]:
    """The entries of ``folder`` that minirt_scenes names but that are neither a file nor a folder (links
    followed): what pytest's own collection skips."""
    import os

    out = []
    try:
        with os.scandir(folder.path) as entries:
            for e in sorted(entries, key=lambda e: e.name):
                path = Path(e.path)
                if e.is_file() or e.is_dir() or not _wanted(path, folder.config):
                    continue
                if not folder.ihook.pytest_ignore_collect(collection_path=path, config=folder.config):
                    out.append(path)
    except OSError:
        pass  # a folder that cannot be listed: pytest's own collection says so
    return out


class SceneFile(pytest.File):
    """A scene file collected as a test (ini minirt_scenes)."""

    def collect(self):
        yield SceneItem.from_parent(self, name="check")


class SceneItem(pytest.Item):
    """``minirt check`` on one scene file: passes when every backend passes."""

    def runtest(self) -> None:
        from minirt.testing import assert_scene_passes

        backends, size = _settings(self.config)
        assert_scene_passes(self.path, backends, size=size or None)

    def repr_failure(self, excinfo, style=None):
        from minirt.errors import MinirtError

        if isinstance(excinfo.value, AssertionError | MinirtError):
            return str(excinfo.value)  # the checks' own words; no traceback into minirt
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.path, None, f"minirt check {self.path.name}"
