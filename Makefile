# The README's two commands: `make demo` and `make test`. Each builds .venv (pinned) first.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test venv bench clean fuzz ros2cli lint

# The real ros2 command line (test/ros/test_ros2_cli.py): a sourced ROS 2 Jazzy, else the build of
# ../shared/ros2cli/build.sh under ROSCLI_PREFIX, made here when it is missing (2-3 min, cached).
ROSCLI_PREFIX ?= $(HOME)/.cache/ros2cli-jazzy
export ROSCLI_PREFIX
ROSCLI_BUILD := ../shared/ros2cli/build.sh

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

test: $(STAMP) ros2cli
	$(BIN)/python -m pytest -q -n 2 --dist loadfile test

ros2cli:
	@if command -v ros2 >/dev/null && command -v colcon >/dev/null; then \
		echo "ros2 command line: $$(command -v ros2)"; \
	elif [ -x $(ROSCLI_PREFIX)/venv/bin/ros2 ] && [ -f $(ROSCLI_PREFIX)/env.sh ]; then \
		echo "ros2 command line: $(ROSCLI_PREFIX)/venv/bin/ros2"; \
	elif [ -f $(ROSCLI_BUILD) ]; then \
		PYTHON=$(PYTHON) ROSCLI_PREFIX=$(ROSCLI_PREFIX) bash $(ROSCLI_BUILD) --no-verify; \
	else \
		echo "no ros2 command line and no $(ROSCLI_BUILD): test/ros/test_ros2_cli.py is skipped"; \
	fi

# ament_flake8 and ament_pep257 on the whole package, as `make test` runs them.
lint: $(STAMP)
	$(BIN)/python -m pytest -q test/project/test_flake8.py test/project/test_pep257.py

# The property tests with a 25x example budget and fresh random examples (minutes, not seconds):
# bags and CSVs (test/cli/test_properties.py), 1,000 mutated flight logs and calibration files
# (test/cli/test_properties_logs.py); the statistics give each command's exits.
fuzz: $(STAMP)
	TAK_HYPOTHESIS_PROFILE=long $(BIN)/python -m pytest -q --hypothesis-show-statistics \
		test/cli/test_properties.py test/cli/test_properties_logs.py

bench: $(STAMP)
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) build install log .pytest_cache
