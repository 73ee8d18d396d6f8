# Set-up and everyday commands. Both `demo` and `test` create .venv/ on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
SAMPLE := samples/middlebury2005-art
OUT := out

.PHONY: demo test wheel-check bench-speed bench-memory train gpu-data clean

# One stamp per install level, so that `make demo` (runtime only: no PyTorch) then
# `make test` (test + train extras) upgrades the same venv; each leaves $(BIN)/cade.
RUNTIME := $(VENV)/.installed-runtime
TESTING := $(VENV)/.installed-test

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(RUNTIME): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(TESTING): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,train]'
	touch $@ $(RUNTIME)

demo: $(RUNTIME)
	mkdir -p $(OUT)
	$(BIN)/cade disparity $(SAMPLE)/left_R.png $(SAMPLE)/right_B.png -o $(OUT)/art_disparity.pfm \
		--max-disp 80 --vis $(OUT)/art_disparity.png
	$(BIN)/cade register --reference $(SAMPLE)/left_R.png --moving $(SAMPLE)/right_B.png -o $(OUT)/art_registered.tif --max-disp 80 \
		--vis $(OUT)/art_registered.png
	@echo "wrote $(OUT)/art_disparity.pfm, $(OUT)/art_disparity.png (colourised), $(OUT)/art_registered.tif," \
		"$(OUT)/art_registered.png (overlay)"

test: $(TESTING)
	$(BIN)/python -m pytest -q

# Speed comparison with CNES Pandora (its own venv: Pandora pins its own dependencies).
bench-speed:
	$(PYTHON) -m venv $(VENV)-bench
	$(VENV)-bench/bin/python -m pip install --quiet -e . -r benchmarks/requirements-speed.txt
	$(VENV)-bench/bin/python benchmarks/speed.py --data-dir ../shared/data/middlebury2014/trainingQ --markdown docs/speed.md

# Peak memory of `cade disparity --method cade` on a generated 3000x2000 (6 MP) pair.
bench-memory: $(RUNTIME)
	$(BIN)/python benchmarks/memory.py --width 3000 --height 2000 --max-disp 200

# Train the CADE network on generated data (torch only here, CPU build pinned) and export
# it to models/: cade-v4 is cade-v3's committed checkpoint fine-tuned into the faster
# design (zero padding, 1x1x1 first 3D kernel). The run resumes from $(RUN)/last.pt when
# it exists. See docs/research/network-design.md.
RUN ?= runs/cade-v4
INIT ?= runs/cade-v3/last.pt
STEPS ?= 6000
train: $(RUNTIME)
	$(BIN)/python -m pip install --quiet -e '.[train,test]'
	$(BIN)/python -m cade_cli.train fit --out $(RUN) --init $(INIT) --textures ../shared/data/textures \
		--data-dir ../shared/data --steps $(STEPS) --lr 5e-4 --warmup 100 --seed 4 --device cpu --threads 2 --workers 1
	$(BIN)/python -m cade_cli.train export $(RUN)/last.pt --onnx models/cade-v4.onnx

# The GPU recipe's carried data (docs/gpu-recipe.md): the real training scenes and three
# texture sets, packed losslessly into .gpu-pack/data.tar (git-ignored) so that they and the
# tracked tree fit one device call; benchmarks/gpu_data.py unpacks them there into .gpu-data/.
gpu-data: $(RUNTIME)
	$(BIN)/python benchmarks/gpu_data.py pack ../shared/data .gpu-pack/data.tar

# A wheel built from this checkout, installed into a fresh venv outside the repo, runs the
# default method on the bundled sample (the models travel inside the wheel). CI runs this.
wheel-check: $(RUNTIME)
	set -e; work=$$(mktemp -d); \
	$(BIN)/python -m pip wheel . --no-deps --quiet -w $$work/dist; \
	$(PYTHON) -m venv $$work/venv; \
	$$work/venv/bin/python -m pip install --quiet $$work/dist/*.whl; \
	cd $$work && venv/bin/cade disparity $(CURDIR)/$(SAMPLE)/left_R.png $(CURDIR)/$(SAMPLE)/right_B.png \
		-o art.pfm --method cade --max-disp 80; \
	rm -rf $$work

clean:
	rm -rf $(OUT) .pytest_cache
