# make run  - set up .venv from nothing and run the HST roll step through the ROS 2 graph,
#             starting on PID and swapping to the hybrid fuzzy PID at 5 s
# make test - set up .venv and the test suite's Node client from nothing, lint, and run the test suite
#             (Node.js and npm are needed by this target only)
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# the live-view tests' Foxglove client (Node): installed for the test suite only, so that every other target
# runs where there is no Node
JS_STAMP := test/js/node_modules/.installed
# the ROS 2 Jazzy wheels, the package with its test extras, and the example law and estimator packages installed
# as a user installs theirs (the suite proves the plugin paths with them)
REQUIREMENTS := 'ros-jazzy-rclpy[fastrtps]' ros-jazzy-common-interfaces ros-jazzy-std-srvs ros-jazzy-rosgraph-msgs \
	-e '.[test]' -e ./examples/custom_law -e ./examples/custom_estimator

.PHONY: run test test-unit lint bench soak docs clean

$(STAMP): setup.py package.xml examples/custom_law/pyproject.toml examples/custom_estimator/pyproject.toml
	$(PYTHON) -m venv $(VENV)
	# uv installs the same wheels as pip in under half the time (downloads and unpacks in parallel; 30 s against
	# 70 s here), byte-compiled as pip does; pip, the venv's own, is the fallback where uv cannot be had
	$(BIN)/pip install --quiet 'uv>=0.5' && $(BIN)/uv pip install --quiet --python $(BIN)/python --compile-bytecode \
		$(REQUIREMENTS) || $(BIN)/pip install --quiet $(REQUIREMENTS)
	# the package's own bytecode, once (pip compiles what it installs, not an editable source tree): where
	# PYTHONDONTWRITEBYTECODE is set, every process would compile it again, 0.2 s of each node's start
	$(BIN)/python -m compileall -q attitude_sil examples/custom_law examples/custom_estimator
	$(BIN)/python -m attitude_sil.tools.warm
	touch $(STAMP)

# the official Foxglove protocol client (Node, pinned in test/js/package-lock.json) the live-view tests run;
# npm ci empties node_modules first, so the stamp inside it goes with an old install
$(JS_STAMP): test/js/package.json test/js/package-lock.json
	cd test/js && npm ci --no-audit --no-fund --silent
	touch $(JS_STAMP)

run: $(STAMP)
	$(BIN)/attitude-sil run config/hst_roll_step.yaml --swap 5:fuzzy_pid

lint: $(STAMP)
	$(BIN)/ruff check attitude_sil test bench launch examples

test: $(STAMP) $(JS_STAMP) lint
	$(BIN)/python -m pytest -q -n auto --dist worksteal test

# the ROS-free layer alone (no graph): about 2 min, 46 s of it the fidelity rows at a tenth of the step
test-unit: $(STAMP)
	$(BIN)/python -m pytest -q test/unit

bench: $(STAMP)
	$(BIN)/python bench/bench_engine.py
	$(BIN)/python bench/bench_tuner.py
	$(BIN)/python bench/bench_cluster.py

soak: $(STAMP)
	$(BIN)/python bench/bench_soak.py

# docs/parameters.md from the schema, then the site (MkDocs) into site/: the guides, the README as home
docs: $(STAMP)
	$(BIN)/python -c "from attitude_sil.core.sim.params import parameters_markdown as p; \
	head = open('docs/parameters.md').read().split('<!-- generated')[0]; \
	open('docs/parameters.md', 'w').write(head + p() + '\n')"
	$(BIN)/pip install --quiet -e '.[docs]'
	rm -rf build/docsite && mkdir -p build/docsite && cp docs/*.md build/docsite/
	sed 's|](docs/|](|g' README.md > build/docsite/index.md
	$(BIN)/mkdocs build --quiet

clean:
	rm -rf $(VENV) build site *.egg-info
