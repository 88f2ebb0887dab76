# Two commands for a newcomer: `make demo` and `make test`. Both set everything up first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
APT_PACKAGES := povray libllvm19 chromium bubblewrap g++

.PHONY: setup system demo sample test lint format bench fuzz goldens schemas clean

setup: system $(STAMP)

# System packages: installed when we are root, otherwise the exact command is printed and we stop.
system:
	@sh tools/system-deps.sh $(APT_PACKAGES)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "minirt needs Python >= 3.11")'
	$(PYTHON) -m venv $(VENV)
	# Blender as a Python module (Cycles, the fourth oracle; ~1 GB) in an environment of its own: bpy 5.0.1
	# needs NumPy < 2, minirt's OpenImageIO and colour-science NumPy >= 2 (README: Install). It installs
	# beside minirt's own packages (both mostly unpack wheels): set-up takes the longer of the two, not both.
	$(PYTHON) -m venv $(VENV)/blender
	@$(VENV)/blender/bin/python -m pip install --quiet bpy==5.0.1 > $(VENV)/blender-install.log 2>&1 & bpy=$$!; \
	echo "$(VENV)/blender/bin/python -m pip install --quiet bpy==5.0.1 (beside the next two)"; \
	$(BIN)/python -m pip install --quiet --upgrade pip && $(BIN)/python -m pip install --quiet -e '.[dev]'; own=$$?; \
	wait $$bpy; blender=$$?; \
	if [ $$blender -ne 0 ]; then cat $(VENV)/blender-install.log; echo "installing bpy failed"; fi; \
	test $$own -eq 0 && test $$blender -eq 0
	@touch $(STAMP)

# The main job: every backend on the exercise scene, the comparison report of all bundled scenes, then
# the headline feature: grade sample "student" images (renders with wrong rules, shipped in scenes/samples;
# the second with bugs seen in real solutions and one no rule explains).
# A FAIL or DIFFERS verdict (exit 1) still leaves a page to read; bad input or a backend error (exit 2) stops.
demo: setup
	$(BIN)/minirt render scenes/exercise.toml --backend all --out renders/exercise
	$(BIN)/minirt report --out reports || test $$? -eq 1
	@echo "open reports/index.html"
	$(BIN)/minirt grade scenes/rules.toml scenes/samples/rules.student.png --out grades/sample || test $$? -eq 1
	@echo "open grades/sample/index.html (the sample student's grade)"
	$(BIN)/minirt grade scenes/three_balls.toml scenes/samples/three_balls.student.png --out grades/sample-real || test $$? -eq 1
	@echo "open grades/sample-real/index.html (bugs seen in real solutions, and pixels no rule explains)"
	mkdir -p grades
	$(BIN)/minirt grade --program scenes/samples/raytracer2014.cpp --json grades/program.json --out grades/program.html || test $$? -eq 1
	@echo "open grades/program.html (a sample 2014 solution graded as a program over the suite, in a sandbox)"

# Refresh the committed sample report (bundled scenes at 64x64, every backend).
sample: setup
	$(BIN)/python -c 'from minirt.pages.report import refresh_sample; refresh_sample()'

test: setup
	$(BIN)/ruff check minirt oracles tests benchmarks tools
	$(BIN)/ruff format --check minirt oracles tests benchmarks tools
	sh tools/lint-imports.sh
	$(BIN)/python -m pytest

lint:
	$(BIN)/ruff check minirt oracles tests benchmarks tools
	sh tools/lint-imports.sh

format:
	$(BIN)/ruff format minirt oracles tests benchmarks tools
	$(BIN)/ruff check --fix minirt oracles tests benchmarks tools

# Refresh the reference tracer's golden images on purpose (after an intended change to its output).
goldens: setup
	MINIRT_UPDATE_GOLDENS=1 $(BIN)/python -m pytest -q tests/reference/test_goldens.py

# Regenerate the shipped JSON Schemas (minirt/io/schemas/) from the document models (after changing a document).
schemas: setup
	$(BIN)/python -m minirt.io.documents

bench: setup
	$(BIN)/python benchmarks/bench.py

# The adversarial campaign in small: hard scenes of every family through every oracle (minirt fuzz; SEED=,
# COUNT=, SIZE= to vary, FAMILY= a comma list of families, DEFECTS=all to check the injected defects too).
fuzz: setup
	$(BIN)/minirt fuzz --seed $(or $(SEED),1) --count $(or $(COUNT),14) --size $(or $(SIZE),24)x$(or $(SIZE),24) \
		--families $(or $(FAMILY),all) --defects $(or $(DEFECTS),none) --out renders/fuzz

clean:
	rm -rf $(VENV) renders out grades .pytest_cache
