# Each target sets up .venv (pinned dependencies) when it is missing or out of date, and precompiles the sources
# (start-up then does not depend on PYTHONDONTWRITEBYTECODE or on a writable source tree). It also compiles, at once
# on two cores, kar-moura's numba kernels for the sizes the estimators use (dse/estimators/gikf_compiled.py
# warm_cache: about 8 s of CPU once, instead of a few seconds in a fresh clone's first kar-moura run and in each test
# process that meets a kernel first) and the test modules as pytest rewrites them for their asserts (about 4 s once,
# instead of in each of `make test`'s four workers; its exit status is ignored: the tests report their own errors).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
EXAMPLE := examples/dse-consensus-measurements

.PHONY: reproduce sweeps arena site test bench check-outputs check-tools check-pages check-viewer check-site clean

# The example plug-in package ($(EXAMPLE), docs/plugins.md) is installed too: its entry point `cm` is what the
# README's `dse arena cm` and tests/test_example_plugin.py find.
$(STAMP): pyproject.toml $(EXAMPLE)/pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	$(BIN)/pip install --quiet --no-deps -e $(EXAMPLE)
	$(BIN)/pip install --quiet --no-deps 'rerun-notebook==0.41.0'   # the [site] extra: the web viewer's files only
	$(BIN)/python -m compileall -q dse benchmarks
	$(BIN)/python -c 'from dse.estimators import gikf_compiled; gikf_compiled.warm_cache()' & kernels=$$!; \
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest --collect-only -q -p no:cacheprovider >/dev/null 2>&1; \
	wait $$kernels
	-$(BIN)/rerun analytics disable >/dev/null 2>&1
	touch $(STAMP)

reproduce: $(STAMP)
	$(BIN)/dse reproduce --out out
	$(MAKE) --no-print-directory sweeps
	$(MAKE) --no-print-directory arena
	$(MAKE) --no-print-directory site

# The example plug-in filter (examples/dse-consensus-measurements, installed by the set-up) against every built-in
# estimator on the quick suite (out/arena/cm/: leaderboard, frontier figure, recording; docs/plugins.md).
arena: $(STAMP)
	$(BIN)/dse arena cm --quick --out out

# The report site of out/ (out/site/index.html; docs/site.md): browse it with
#   python -m http.server -d out/site
site: $(STAMP)
	$(BIN)/dse site out

# The shipped example sweeps (dse/families/sweeps/*.toml), one after the other on one local Dask cluster
# (about a minute and a half of CPU together; `make bench`, section sweep, times them).
sweeps: $(STAMP)
	$(BIN)/dse sweep dse/families/sweeps/*.toml --out out

# Two test processes per core (pytest-xdist: many tests wait on subprocesses, signals or a Dask cluster, and
# the second process fills those waits; 184 s instead of 213 s with one per core on 2 cores); each test file
# stays in one process, so that a module's fixtures (a paper's quick reproduction, say) are computed once; the
# files go out longest first, in the order tests/conftest.py collects them (LONGEST_FILES). Bytecode writing is
# allowed for the run (PYTHONDONTWRITEBYTECODE emptied): pytest keeps the test modules as rewritten for its asserts in
# tests/__pycache__, and each worker's collection then reads them (3.4 s of CPU instead of 6.1 s per worker).
test: $(STAMP)
	PYTHONDONTWRITEBYTECODE= OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -n $$(( 2 * $$(nproc) )) --dist loadfile --no-loadscope-reorder

# The outputs both checks below look at, computed once into out/checks (the second target finds them done: the run
# memos, stored sweep points and reused figures make its commands take seconds): a quick reproduction, a compare run,
# one example sweep and the example plug-in's quick arena.
CHECK_OUT := out/checks
check-outputs: $(STAMP)
	$(BIN)/dse reproduce --quick --out $(CHECK_OUT)
	$(BIN)/dse run --quick dse/families/compare/scenarios/noisy_ring.toml --out $(CHECK_OUT)
	$(BIN)/dse sweep dse/families/sweeps/compare_links_noise_size.toml --out $(CHECK_OUT)
	$(BIN)/dse arena cm --quick --out $(CHECK_OUT)

# What the two checks below need besides the project's environment, installed once before either starts (they may run
# at once, as .ci/run has them, and two apt-get at a time would contend for dpkg's lock): software Vulkan for Rerun's
# viewer (Debian's mesa-vulkan-drivers), Debian's chromium and Playwright to drive it (new packages in the venv only,
# none that check-outputs' commands import).
check-tools: $(STAMP)
	@{ dpkg -s mesa-vulkan-drivers >/dev/null 2>&1 && command -v chromium >/dev/null 2>&1; } || \
		{ apt-get update -qq && apt-get install -y -qq mesa-vulkan-drivers chromium; }
	$(BIN)/pip install --quiet 'playwright==1.65.2'

# The report site of those outputs (out/checks/site), built before either check starts: the viewer check opens every
# recording under out/checks but the site's copies, and a site being built (out/checks/site.staging-PID) would be
# among them.
check-pages: check-outputs
	$(BIN)/dse site $(CHECK_OUT)

# Opens every recording of those outputs in Rerun's own viewer (headless, software Vulkan, three viewers at a time)
# and checks the views render without errors; the screenshots it takes are the README's.
check-viewer: check-tools check-pages
	rm -rf $(CHECK_OUT)/viewer-screenshots
	$(BIN)/python -m dse.outputs.viewer_check $(CHECK_OUT) --screenshots $(CHECK_OUT)/viewer-screenshots

# Loads every page of those outputs' report site in headless Chromium (Debian's chromium package, driven by
# Playwright with that executable: no browser download): no console error, no failed request, every image loaded, a
# table sorts, the claim filter filters, and a recording of every family renders in the web viewer. The screenshots it
# takes are the README's.
check-site: check-tools check-pages
	rm -rf $(CHECK_OUT)/site-screenshots
	$(BIN)/python -m dse.site.browser_check $(CHECK_OUT)/site --screenshots $(CHECK_OUT)/site-screenshots

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run --out out

# What the targets above write: the outputs (out/, the stage cache out/.cache/ inside it) and the test
# runs' caches; .venv/ is kept (`rm -rf .venv` rebuilds it on the next target).
clean:
	rm -rf out .pytest_cache .hypothesis
