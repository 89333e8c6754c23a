#!/usr/bin/env bash
# The farm beside the trainers a researcher would pick instead, on the same GesTHOR
# env, the same cores and the same frame budget, one after another:
#   ours     `orchestrator up` on configs/tiny/both.toml, then `orchestrator eval` on the run
#   sf       Sample Factory 2 APPO (scripts/peers/sf_gesthor.py), its own worker processes
#   cleanrl  a CleanRL-style PPO on `gesthor.make_vec` (scripts/peers/cleanrl_ppo.py)
# each followed by SR at the first stop on the same val programs, then one table:
# OUT/results.md and OUT/results.json. Not part of the test path. Both peers have the default's
# network (scripts/peers/net.py): the frozen encoder of the config's model.encoder_weights run
# once per frame when acting, its features stored, the layers above trained; every trainer's
# frames are the env steps it trained on, the step that starts an episode included.
#
# Usage: scripts/peers.sh [FRAMES]       (default 1000000; or PEERS_FRAMES)
#   PEERS_EVAL_PROGRAMS  val programs for SR (500)
#   PEERS_OUT            output folder (~/.cache/gesthor/peers-run); each trainer logs to OUT/NAME/
#   PEERS_ONLY           trainers to run, comma-separated (ours,sf,cleanrl); the others' results stay
#   PEERS_SETUP_ONLY=1   install the peers and assemble the package, run nothing
# Needs target/release/{orchestrator,lib_gesthor.so} (cargo build --release) and scripts/setup.sh's
# ~/.cache/gesthor (the PyTorch 2.11 wheel unpacked, env.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

FRAMES=${1:-${PEERS_FRAMES:-1000000}}
PROGRAMS=${PEERS_EVAL_PROGRAMS:-500}
OUT=${PEERS_OUT:-$HOME/.cache/gesthor/peers-run}
ONLY=${PEERS_ONLY:-ours,sf,cleanrl}
DEPS=$HOME/.cache/gesthor
PEERS=$DEPS/peers
TORCH=$DEPS/torch-2.11.0
CONFIG=configs/tiny/both.toml
DATASET=data/gond

log() { echo "[peers] $*" >&2; }
now() { date +%s.%N; }

[[ -f $DEPS/env.sh && -d $TORCH/torch ]] || { log "run scripts/setup.sh first (no $TORCH)"; exit 1; }
[[ -x target/release/orchestrator && -f target/release/lib_gesthor.so ]] ||
  { log "build first: cargo build --release (target/release/orchestrator, lib_gesthor.so)"; exit 1; }
[[ -f $DATASET/manifest.json ]] || { log "no dataset at $DATASET"; exit 1; }

# --- the peers' Pythons ---------------------------------------------------------------------
# The unpacked torch wheel is cp312: the venvs run Python 3.12 and find it through a .pth file.
# Its CUDA build needs the CUDA libraries to import even on CPU: their wheels (no driver needed)
# go into one folder on the same .pth, and torch preloads them from there.
PY312=${PEERS_PYTHON:-}
if [[ -z $PY312 ]]; then
  # a pyenv shim named python3.12 may exist and refuse to run: take the first that runs
  for p in "$(command -v python3.12 || true)" "$HOME"/.pyenv/versions/3.12.*/bin/python3; do
    if [[ -x $p ]] && "$p" -c 'import sys; assert sys.version_info[:2] == (3, 12)' 2>/dev/null; then PY312=$p; break; fi
  done
fi
[[ -n $PY312 ]] || { log "needs Python 3.12 (the torch wheel is cp312): set PEERS_PYTHON"; exit 1; }

CUDA_REQS="nvidia-cudnn-cu13==9.19.0.56 nvidia-cusparselt-cu13==0.8.0 nvidia-nccl-cu13==2.28.9 nvidia-nvshmem-cu13==3.4.5
nvidia-cublas==13.1.0.3.* nvidia-cuda-nvrtc==13.0.88.* nvidia-cufft==12.0.0.61.* nvidia-cufile==1.15.1.6.*
nvidia-curand==10.4.0.35.* nvidia-cusolver==12.0.4.66.* nvidia-cusparse==12.6.3.3.* nvidia-nvjitlink==13.0.88.*
nvidia-nvtx==13.0.85.*"
TORCH_DEPS="filelock typing-extensions>=4.10.0 setuptools<82 sympy>=1.13.3 networkx>=2.5.1 jinja2 fsspec>=0.8.5"
# gesthor.make_vec needs gymnasium 1.x
CLEANRL_REQS="numpy>=2 gymnasium==1.4.0 $TORCH_DEPS"
# Sample Factory 2.1.1 pins numpy < 2 and gymnasium < 1.0; it is installed without its
# dependencies (they would pull another torch) and those listed by hand (opencv headless: no GUI)
SF_REQS="numpy<2 gymnasium==0.29.1 pyglet tensorboard>=1.15.0 tensorboardx>=2.0 psutil>=5.7.0 threadpoolctl>=2.0.0
colorlog signal-slot-mp>=1.0.3,<2.0 opencv-python-headless<4.11 wandb>=0.12.9 huggingface-hub>=0.10.0,<1.0 $TORCH_DEPS"

installed() { [[ -f $1 && "$(cat "$1")" == "$2" ]]; }

if ! installed "$PEERS/cuda13/.done" "$CUDA_REQS"; then
  log "CUDA library wheels for torch's import (about 2.6 GB) into $PEERS/cuda13"
  rm -rf "$PEERS/cuda13"
  # shellcheck disable=SC2086
  "$PY312" -m pip install -q --no-deps --target "$PEERS/cuda13" $CUDA_REQS
  echo "$CUDA_REQS" >"$PEERS/cuda13/.done"
fi

make_venv() { # NAME REQS [EXTRA --no-deps PACKAGE]
  local d=$PEERS/$1 want="$2 ${3:-}"
  installed "$d/.done" "$want" && return
  log "venv $d"
  [[ -x $d/bin/python ]] || "$PY312" -m venv "$d"
  local sp
  sp=$("$d/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  printf '%s\n%s\n' "$TORCH" "$PEERS/cuda13" >"$sp/gesthor-torch.pth"
  # shellcheck disable=SC2086
  "$d/bin/pip" install -q $2 2>&1 | grep -v "torch 2.11.0 requires\|dependency resolver\|dependency conflicts" || true
  if [[ -n ${3:-} ]]; then
    "$d/bin/pip" install -q --no-deps "$3"
  fi
  "$d/bin/python" -c 'import torch, gymnasium, numpy; torch.ones(1).sum()'
  echo "$want" >"$d/.done"
}
make_venv cleanrl "$CLEANRL_REQS"
make_venv sf "$SF_REQS" sample-factory==2.1.1

# --- the gesthor package, as tests/python_package.rs assembles it ---------------------------
PKG=$PEERS/pkg
rm -rf "$PKG" && mkdir -p "$PKG/gesthor"
cp python/gesthor/*.py "$PKG/gesthor/"
cp target/release/lib_gesthor.so "$PKG/gesthor/_gesthor.abi3.so"
export PYTHONPATH=$PKG
[[ ${PEERS_SETUP_ONLY:-0} == 1 ]] && { log "set up; nothing run"; exit 0; }

mkdir -p "$OUT"
cat >"$OUT/meta.json" <<EOF
{"date": "$(date -u +%Y-%m-%dT%H:%MZ)", "commit": "$(git rev-parse --short HEAD 2>/dev/null || echo '?')",
 "cpus": $(nproc), "cpu": "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)",
 "command": "scripts/peers.sh $FRAMES (PEERS_EVAL_PROGRAMS=$PROGRAMS)"}
EOF
wants() { [[ ,$ONLY, == *,$1,* ]]; }
times() { printf '{"train_s": %s, "eval_s": %s}\n' "$2" "$3" >"$OUT/$1/times.json"; }

if wants ours; then
  d=$OUT/ours && rm -rf "$d" && mkdir -p "$d"
  log "ours: orchestrator up, $FRAMES frames (log $d/train.log)"
  t0=$(now)
  # run.total_frames is what the learning rate decays over (to 0), as CleanRL's over its budget
  ( source "$DEPS/env.sh" && exec target/release/orchestrator up --config "$CONFIG" --frames "$FRAMES" \
      --set run.total_frames="$FRAMES" --run-dir "$d/run" ) >"$d/train.log" 2>&1
  t1=$(now)
  log "ours: orchestrator eval on $PROGRAMS val programs (log $d/eval.log)"
  ( source "$DEPS/env.sh" && exec target/release/orchestrator eval --checkpoint "$d/run" --split val \
      --max-programs "$PROGRAMS" --modes normal --out "$d/eval" ) >"$d/eval.log" 2>&1
  t2=$(now)
  times ours "$(echo "$t1 - $t0" | bc)" "$(echo "$t2 - $t1" | bc)"
fi

# torch's OpenMP threads wait as the orchestrator has its learner's wait (orchestrator/src/
# supervise/child.rs: a short spin, then sleep), unless set already: spinning long for a
# partner thread that is not scheduled is slow on 2 busy cores
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE} GOMP_SPINCOUNT=${GOMP_SPINCOUNT:-30000}

if wants sf; then
  d=$OUT/sf && rm -rf "$d" && mkdir -p "$d"
  # it stops once its count passes the budget (one fewer: once it reaches it, as ours); APPO's
  # batches in flight then are trained on too, and counted
  log "Sample Factory APPO, $FRAMES frames (log $d/train.log)"
  t0=$(now)
  "$PEERS/sf/bin/python" scripts/peers/sf_gesthor.py train --train_dir "$d" --experiment appo \
    --train_for_env_steps "$((FRAMES - 1))" --gesthor_config "$CONFIG" --gesthor_dataset "$DATASET" >"$d/train.log" 2>&1
  t1=$(now)
  log "Sample Factory: SR on $PROGRAMS val programs (log $d/eval.log)"
  "$PEERS/sf/bin/python" scripts/peers/sf_gesthor.py eval --train_dir "$d" --experiment appo \
    --eval_programs "$PROGRAMS" --out "$d/eval.json" >"$d/eval.log" 2>&1
  t2=$(now)
  times sf "$(echo "$t1 - $t0" | bc)" "$(echo "$t2 - $t1" | bc)"
fi

if wants cleanrl; then
  d=$OUT/cleanrl && rm -rf "$d" && mkdir -p "$d"
  log "CleanRL-style PPO, $FRAMES frames, then SR on $PROGRAMS val programs (log $d/train.log)"
  t0=$(now)
  "$PEERS/cleanrl/bin/python" scripts/peers/cleanrl_ppo.py --total_timesteps "$FRAMES" --config "$CONFIG" \
    --dataset "$DATASET" --eval_programs "$PROGRAMS" --out "$d" >"$d/train.log" 2>&1
  t2=$(now)
  # its evaluation runs in the same process, after training: split by its own clock
  train_s=$("$PEERS/cleanrl/bin/python" -c 'import json,sys; print(json.load(open(sys.argv[1]))["train_seconds"])' "$d/results.json")
  times cleanrl "$train_s" "$(echo "$t2 - $t0 - $train_s" | bc)"
fi

python3 scripts/peers/report.py "$OUT" "$FRAMES" "$PROGRAMS"
log "table: $OUT/results.md"
