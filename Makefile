# Set-up and everyday commands. Both `demo` and `test` create .venv/ on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
SAMPLE := samples/middlebury2005-art
OUT := out

.PHONY: demo test bench-speed clean

$(BIN)/cade: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

demo: $(BIN)/cade
	mkdir -p $(OUT)
	$(BIN)/cade disparity $(SAMPLE)/left_R.png $(SAMPLE)/right_B.png -o $(OUT)/art_disparity.pfm \
		--max-disp 80 --vis $(OUT)/art_disparity.png
	$(BIN)/cade register $(SAMPLE)/right_B.png $(SAMPLE)/left_R.png -o $(OUT)/art_registered.tif --max-disp 80
	@echo "wrote $(OUT)/art_disparity.pfm, $(OUT)/art_disparity.png (colourised), $(OUT)/art_registered.tif"

test: $(BIN)/cade
	$(BIN)/python -m pytest -q

# Speed comparison with CNES Pandora (its own venv: Pandora pins its own dependencies).
bench-speed:
	$(PYTHON) -m venv $(VENV)-bench
	$(VENV)-bench/bin/python -m pip install --quiet -e . -r benchmarks/requirements-speed.txt
	$(VENV)-bench/bin/python benchmarks/speed.py --data-dir ../shared/data/middlebury2014/trainingQ --markdown docs/speed.md

clean:
	rm -rf $(OUT) .pytest_cache
