#!/bin/sh
# minirt's declared layers (pyproject.toml, [tool.importlinter]), checked by import-linter.
# import-linter reads a package from one folder, and minirt.oracles lives in oracles/ (pyproject.toml's
# package-dir), so the check runs on a copy of the sources laid out as the wheel lays them out.
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
view=$(mktemp -d)
trap 'rm -rf "$view"' EXIT INT TERM
cp -R "$root/minirt" "$view/minirt"
cp -R "$root/oracles" "$view/minirt/oracles"
cp "$root/pyproject.toml" "$view/"
cd "$view"
PYTHONPATH="$view" "$root/.venv/bin/lint-imports" pyproject.toml --no-cache
