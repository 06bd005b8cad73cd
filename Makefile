# The README's two commands: `make demo` and `make test`. Each builds .venv (pinned) first.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test venv bench clean fuzz

venv: $(STAMP)

$(STAMP): requirements.txt constraints.txt setup.py setup.cfg package.xml
	$(PYTHON) -c 'import sys; assert sys.version_info[:2] == (3, 11), "Python 3.11 is required (ROS 2 Jazzy wheels)"'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -r requirements.txt -c constraints.txt
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	# setup.cfg installs the executables under lib/tak_thermo_ros (where `ros2 run` looks);
	# link them into .venv/bin as well so that they are on the venv's PATH.
	ln -sf ../lib/tak_thermo_ros/tak_calib $(BIN)/tak_calib
	ln -sf ../lib/tak_thermo_ros/compensator $(BIN)/compensator
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python demo/demo.py

test: $(STAMP)
	$(BIN)/python -m pytest -q test

# The property tests with a 25x example budget and fresh random examples (minutes, not seconds).
fuzz: $(STAMP)
	TAK_HYPOTHESIS_PROFILE=long $(BIN)/python -m pytest -q test/test_properties_cli.py

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) build install log .pytest_cache
