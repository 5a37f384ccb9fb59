# The README's commands. Everything runs from the repository's .venv (made by `make setup`).
PYTHON := .venv/bin/python
SAMPLE_BAG ?= bags/sample
# the product's network (msfsu_bringup/product.yaml)
CHECKPOINT ?= $(shell $(PYTHON) -m msfsu_bringup.product checkpoint 2>/dev/null)
RUN_DIR ?= runs/demo
AEB ?= 1

.PHONY: setup test test-all demo default-model model-v3 waiting waiting-realtime colcon-build

setup:  ## one command from a fresh clone: venv, pinned deps, messages, packages (idempotent; TORCH=cuda: GPU builds)
	TORCH=$(TORCH) bash scripts/setup.sh

test:  ## default suite (unit + in-process ROS graph + short simulator runs), under 10 min on 2 cores: one worker a core
	$(PYTHON) -m pytest -n 2 --dist loadfile --max-worker-restart 0

test-all:  ## everything, including tests marked slow (long simulator episodes, training runs)
	$(PYTHON) -m pytest -m ""

demo:  ## open-loop metrics of the default model on the held-out sample bag (CLOSED_LOOP=1: + one sim route; AEB=0: without the emergency brake)
	AEB=$(AEB) bash scripts/demo.sh "$(SAMPLE_BAG)" "$(CHECKPOINT)" "$(RUN_DIR)"

default-model:  ## the recipe of the shipped models/ and bags/sample: collect, DAgger rounds, train MSFSU/MSF/SU, release (hours on 2 cores; STAGES=...: these)
	.venv/bin/msfsu-default-model $(STAGES)

model-v3:  ## the shipped models trained further in stages on a 16 h budget (issue 58; COMMIT=1: commit each stage; STAGES=...: these)
	COMMIT=$(COMMIT) .venv/bin/msfsu-model-v3 $(STAGES)

waiting:  ## issue 77: the shipped MSFSU trained to wait (stop output vs weighted speed loss), judged and released in stages (COMMIT=1; STAGES=...)
	COMMIT=$(COMMIT) .venv/bin/msfsu-waiting $(STAGES)

WAITING_SELECTION = docs/results/waiting/selection.json
WAITING_CANDIDATE = $(shell $(PYTHON) -c "import json; print(json.load(open('$(WAITING_SELECTION)'))['chosen'])" 2>/dev/null)
waiting-realtime:  ## issue 77's real-time goal, alone on the machine: the gated precision's rate and the deployed graph's 20 Hz soak, shipped MSFSU and the chosen candidate in one run
	@test -n "$(WAITING_CANDIDATE)" || { echo "waiting-realtime: no chosen candidate in $(WAITING_SELECTION): the select stage writes it (make waiting STAGES=select)" >&2; exit 2; }
	for agent in msfsu=models/msfsu_default.pt $(WAITING_CANDIDATE)=checkpoints/waiting/$(WAITING_CANDIDATE).pt; do \
		name=$${agent%%=*}; checkpoint=$${agent#*=}; \
		$(PYTHON) benchmarks/perception.py --models cpu --cpu-checkpoint $$checkpoint --e2e-frames 0 \
			--out benchmarks/waiting/perception_$$name.md --json benchmarks/waiting/perception_$$name.json || exit 1; \
		$(PYTHON) benchmarks/soak.py --minutes 3 --rate 20 --aeb-crossing --checkpoint $$checkpoint \
			--out-dir benchmarks/soak/waiting/$$name || exit 1; \
	done

colcon-build:  ## build ros2_ws the ROS way (install/ in ros2_ws), against the pip ROS 2
	cd ros2_ws && AMENT_PREFIX_PATH=$(CURDIR)/.venv CMAKE_PREFIX_PATH=$(CURDIR)/.venv \
		../.venv/bin/colcon build --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE=$(CURDIR)/$(PYTHON)
