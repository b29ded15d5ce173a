# Two commands do all the set-up on a fresh machine:
#   make demo   create .venv, install, run the main job
#   make test   create .venv, install, run the test suite
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP_EXTRA ?=
STAMP := $(VENV)/.installed
SEED ?= 0

.PHONY: demo test test-fast bench train train-pybullet train-track train-track-pybullet train-camera train-residual results sweep lint docs clean

DEMO_STAMP := $(VENV)/.installed-demo

# `make test` (and every target but demo) installs the dev extra: everything, with the test, lint and docs tools.
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) .ci/check_python.py
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install $(PIP_EXTRA) -c constraints.txt -e ".[dev]"
	touch $(STAMP)

# `make demo` installs the demo extra only (the envs and onnxruntime, no torch: the shipped policies run as their
# ONNX bundles); into a venv that has the dev extra already, it adds nothing.
$(DEMO_STAMP): pyproject.toml constraints.txt
	$(PYTHON) .ci/check_python.py --demo
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install $(PIP_EXTRA) -c constraints.txt -e ".[demo]"
	touch $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(PY) -m stewart_gym demo

# The suite on three worker processes (pytest-xdist; the Ray sweeps share one worker, so no two clusters start
# at once). Three on 2 cores, because many tests wait on real time (a serial link, a board's timeouts, another
# process) and the third keeps the cores busy meanwhile: about 13 minutes on 2 cores (tests page).
# `$(PY) -m pytest` alone runs it in one process.
test: $(STAMP)
	$(PY) -m pytest -q -n 3 --dist loadgroup

# Every module's fast tests (those not marked slow: training runs, Ray sweeps, long evaluations, the fresh-venv
# install, the 1,000,000-action fuzz), on three worker processes: a few minutes, for the edit-test loop.
test-fast: $(STAMP)
	$(PY) -m pytest -q -n 3 --dist loadgroup -m "not slow"

bench: $(STAMP)
	$(PY) bench/bench_kinematics.py
	$(PY) bench/bench_ik_load.py
	$(PY) bench/bench_sim.py
	$(PY) bench/bench_env.py
	$(PY) bench/bench_batched.py
	$(PY) bench/bench_deploy.py
	$(PY) bench/bench_analysis.py
	$(PY) bench/bench_mujoco.py
	$(PY) bench/bench_camera.py
	$(PY) bench/bench_libraries.py

# Reproduce the camera-trained policy (policies/balance_camera): fine-tune the shipped balance policy (make train's
# run, behind the Kalman observer) with the camera model, a preset per episode (300k steps, about 6 minutes).
train-camera: $(STAMP)
	$(PY) -m stewart_gym train --sensor camera --resume stewart_gym/policies/balance --hyperparams ppo_camera --run-dir runs/camera --overwrite --no-progress
	for s in webcam30 pixy2 global90; do $(PY) -m stewart_gym evaluate --policy runs/camera --sensor $$s --episodes 100; done

# The residual PPO policies as shipped: for balance, 6 learned corrections of the LQR -> PID's approach, for
# track 6 corrections of the LQR -> PID's catching up with the moving target (seeds 0-5, 300k steps each), each 6
# averaged into one policy (`stewart-gym ensemble`). The 12 trainings run TRAIN_JOBS at a time (2 by default), a
# core each: about 40 minutes on 2 cores. On one machine a run depends only on its seed, so the networks are the
# same at any TRAIN_JOBS; another machine's torch and BLAS give other networks that settle as fast.
TRAIN_JOBS ?= 2
RESIDUAL_SEEDS := 0 1 2 3 4 5
train-residual: $(STAMP)
	printf '%s\n' $(RESIDUAL_SEEDS) | xargs -P $(TRAIN_JOBS) -I{} $(PY) -m stewart_gym train --hyperparams stewart_gym/hyperparams/ppo_residual.yml --run-dir runs/residual_balance_s{} --seed {} --overwrite --no-progress
	rm -rf runs/residual_balance
	$(PY) -m stewart_gym ensemble $(patsubst %,runs/residual_balance_s%,$(RESIDUAL_SEEDS)) --out runs/residual_balance --note "ppo_residual.yml, seeds 0-5"
	printf '%s\n' $(RESIDUAL_SEEDS) | xargs -P $(TRAIN_JOBS) -I{} $(PY) -m stewart_gym train --env StewartBallTrack-v0 --hyperparams stewart_gym/hyperparams/ppo_residual.yml --run-dir runs/residual_track_s{} --seed {} --overwrite --no-progress
	rm -rf runs/residual_track
	$(PY) -m stewart_gym ensemble $(patsubst %,runs/residual_track_s%,$(RESIDUAL_SEEDS)) --out runs/residual_track --note "ppo_residual.yml track, seeds 0-5"
	$(PY) -m stewart_gym evaluate --policy runs/residual_balance --episodes 100
	$(PY) -m stewart_gym evaluate --policy runs/residual_track --episodes 100

# The docs' control page (learned vs PID vs LQR), regenerated: the `make train` recipe (batched, about 30 s
# each), the `make train-pybullet` recipe and the same with the error integral observed (3 minutes each, one at a
# time: side by side each would get fewer steps in its 3 minutes), the first balance residual, over the PID +
# Kalman, and the approach residual as one network, each trained with 3 seeds; the shipped balance residual's
# recipe (6 networks averaged) drawn 3 times, seeds 0-5, 6-11 and 12-17 (these TRAIN_JOBS at a time, as in
# train-residual: about 45 minutes, 2.5 hours one after another in worker processes); the shipped track residual's
# recipe drawn twice more, seeds 6-11 and 12-17 (TRAIN_JOBS at a time: 77 minutes on a slow day), its shipped draw
# being the first; the PPO tracker in PyBullet (make train-track-pybullet's recipe) with seeds 0-2, TRAIN_JOBS at a
# time (about 15 minutes), and on the batched backend (make train-track's; 1-3 minutes each); then every
# evaluation, with the shipped track residual's 6 networks one by one (about 1 hour). About 3 hours on 2 cores.
ENSEMBLE_DRAWS := 0 1 2
# $(call residual_draws,DRAWS,NAME,TRAIN_ARGS): the shipped residual recipe drawn once per d in DRAWS, its 6 networks
# (seeds 6d to 6d + 5, TRAIN_JOBS at a time) in runs/NAME_d<d>_s<seed>, averaged into runs/NAME_d<d>.
define residual_draws
for d in $(1); do \
	  seq $$((6 * d)) $$((6 * d + 5)) | xargs -P $(TRAIN_JOBS) -I{} $(PY) -m stewart_gym train $(3) --hyperparams stewart_gym/hyperparams/ppo_residual.yml --run-dir runs/$(2)_d$${d}_s{} --seed {} --overwrite --no-progress || exit 1; \
	  rm -rf runs/$(2)_d$$d; $(PY) -m stewart_gym ensemble runs/$(2)_d$${d}_s* --out runs/$(2)_d$$d || exit 1; \
	done
endef
TRACK_NETS := stewart_gym/policies/track_residual/members
TRACK_DRAWS := 1 2
results: $(STAMP)
	for s in 0 1 2; do $(PY) -m stewart_gym train --env StewartBallBalance-v0 --algo ppo --run-dir runs/scratch_s$$s --seed $$s --max-minutes 3 --overwrite --no-progress; done
	for s in 0 1 2; do $(PY) -m stewart_gym train --hyperparams ppo_batched --run-dir runs/batched_s$$s --seed $$s --max-minutes 3 --overwrite --no-progress; done
	for s in 0 1 2; do $(PY) -m stewart_gym train --env StewartBallBalance-v0 --algo ppo --hyperparams ppo_integral --run-dir runs/integral_s$$s --seed $$s --max-minutes 3 --overwrite --no-progress; done
	printf '%s\n' 0 1 2 | xargs -P $(TRAIN_JOBS) -I{} $(PY) -m stewart_gym train --hyperparams ppo_residual_pid_kalman --run-dir runs/residual_bal_s{} --seed {} --overwrite --no-progress
	printf '%s\n' 0 1 2 | xargs -P $(TRAIN_JOBS) -I{} $(PY) -m stewart_gym train --hyperparams ppo_residual_single --run-dir runs/approach_s{} --seed {} --overwrite --no-progress
	$(call residual_draws,$(ENSEMBLE_DRAWS),ensemble,)
	$(call residual_draws,$(TRACK_DRAWS),track_ens,--env StewartBallTrack-v0)
	printf '%s\n' 0 1 2 | xargs -P $(TRAIN_JOBS) -I{} $(PY) -m stewart_gym train --env StewartBallTrack-v0 --run-dir runs/track_s{} --seed {} --overwrite --no-progress
	for s in 0 1 2; do $(PY) -m stewart_gym train --env StewartBallTrack-v0 --hyperparams ppo_batched --run-dir runs/track_batched_s$$s --seed $$s --overwrite --no-progress; done
	$(PY) train/tools/results.py --recipe "PPO batched, make train=runs/batched_s0,runs/batched_s1,runs/batched_s2" --recipe "PPO in PyBullet, make train-pybullet=runs/scratch_s0,runs/scratch_s1,runs/scratch_s2" --recipe "PPO + error integral=runs/integral_s0,runs/integral_s1,runs/integral_s2" --recipe "residual PPO over the PID + Kalman=runs/residual_bal_s0,runs/residual_bal_s1,runs/residual_bal_s2" --recipe "residual PPO on the approach, one network=runs/approach_s0,runs/approach_s1,runs/approach_s2" --recipe "residual PPO on the approach, 6 networks averaged=runs/ensemble_d0,runs/ensemble_d1,runs/ensemble_d2" --recipe "residual PPO tracker, one network=$(TRACK_NETS)/0,$(TRACK_NETS)/1,$(TRACK_NETS)/2,$(TRACK_NETS)/3,$(TRACK_NETS)/4,$(TRACK_NETS)/5" --recipe "residual PPO tracker, 6 networks averaged=stewart_gym/policies/track_residual,runs/track_ens_d1,runs/track_ens_d2" --recipe "PPO tracker in PyBullet, make train-track-pybullet=runs/track_s0,runs/track_s1,runs/track_s2" --recipe "PPO tracker batched, make train-track=runs/track_batched_s0,runs/track_batched_s1,runs/track_batched_s2"

# The PPO sweep reported in the docs (Ray Tune on this machine's cores): about 20 minutes on 2 cores.
sweep: $(STAMP)
	$(PY) -m stewart_gym sweep train/sweeps/ppo_balance.yaml --out sweeps/ppo_balance

# Train a balance policy from scratch: PPO behind the Kalman observer on the batched backend (128 copies stepped
# together, 300k steps: 20 s to a minute on 2 cores; `make train SEED=1` for another training seed), then evaluate
# it on the 100 seeds in PyBullet.
train: $(STAMP)
	$(PY) -m stewart_gym train --hyperparams ppo_batched --run-dir runs/ppo_balance --seed $(SEED) --max-minutes 3 --overwrite
	$(PY) -m stewart_gym evaluate --env StewartBallBalance-v0 --policy runs/ppo_balance/model.zip --episodes 100

# The same in PyBullet, as the shipped PPO was trained: 3 minutes of wall time on 2 cores.
train-pybullet: $(STAMP)
	$(PY) -m stewart_gym train --env StewartBallBalance-v0 --algo ppo --run-dir runs/ppo_balance_pybullet --seed $(SEED) --max-minutes 3 --overwrite
	$(PY) -m stewart_gym evaluate --env StewartBallBalance-v0 --policy runs/ppo_balance_pybullet/model.zip --episodes 100

# Train a tracking policy from scratch: PPO behind the Kalman observer on the circle, figure-8 and waypoints, one
# drawn per episode, on the batched backend (64 copies, 600k steps: 1-3 minutes on 2 cores), then evaluate it on
# each trajectory's 100 seeds in PyBullet. `make train-track SEED=1` for another seed.
train-track: $(STAMP)
	$(PY) -m stewart_gym train --env StewartBallTrack-v0 --hyperparams ppo_batched --run-dir runs/ppo_track --seed $(SEED) --max-minutes 6 --overwrite
	for t in circle figure8 waypoints; do $(PY) -m stewart_gym evaluate --env StewartBallTrack-v0 --trajectory $$t --policy runs/ppo_track --episodes 100 || exit 1; done

# The same in PyBullet, as the shipped tracker (`--policy shipped --env StewartBallTrack-v0`) was trained (300k
# steps): 10 min 52 s on 2 cores on a slow day (8 minutes of it training).
train-track-pybullet: $(STAMP)
	$(PY) -m stewart_gym train --env StewartBallTrack-v0 --run-dir runs/ppo_track_pybullet --seed $(SEED) --overwrite
	for t in circle figure8 waypoints; do $(PY) -m stewart_gym evaluate --env StewartBallTrack-v0 --trajectory $$t --policy runs/ppo_track_pybullet --episodes 100 || exit 1; done

lint: $(STAMP)
	$(PY) -m ruff check stewart_gym tests bench train
	$(VENV)/bin/lint-imports

# The manual (MkDocs Material) into site/; `$(VENV)/bin/mkdocs serve -f docs/mkdocs.yml` to browse it live.
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict -f docs/mkdocs.yml

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis site
