#!/usr/bin/env bash
# The GPU check, for a CUDA machine without network access: the project's wheels in .whl/ (`pip download` of the
# project and its dependencies) and the EGL Debian packages in .gl/ (`apt-get download libegl1 libegl-mesa0 …`),
# both copied beside the checkout. Writes what it measured under $OUT (docs/gpu.md).
#
#   bash bench/gpu_check.sh speed            learner_speed and loop_speed on cuda (about 3 minutes)
#   bash bench/gpu_check.sh loop             loop_speed at 4 envs, as CUDA graphs and then torch.compile + CUDA graphs
#   bash bench/gpu_check.sh learn MINUTES    learning runs side by side on the GPU for MINUTES: VICE-RAQ on the
#                                            pusher (4 envs, stops at 90%), the door and the picker, each with its task
#                                            settings, for each seed in SEEDS (default 0; SEEDS="0 1 2": 9 runs)
#   bash bench/gpu_check.sh pusher MINUTES   VICE-RAQ on the pusher (4 envs, stops at 90%) for each seed in SEEDS (default
#                                            "3 4 5") side by side, each stopped after MINUTES
#   bash bench/gpu_check.sh door-sweep MIN   the door's classifier sweep, 8 runs side by side: {5, 10, 100} steps
#                                            per epoch x lr {1e-4, 3e-4} (the paper: 5 steps was best), and 5 and 10
#                                            steps at 3e-4 with a query every 1,000 steps and the "no" answers as a
#                                            quarter of the negatives (docs/design.md: the door's settings)
#   bash bench/gpu_check.sh all SECONDS      the whole check within SECONDS (default 540, the pip install counted):
#                                            VICE-RAQ on the pusher alone on the machine (4 envs, seed 0, stops at 90%
#                                            or after PUSHER_ALONE_MINUTES, default 3.5: the time to 90% on a GPU),
#                                            then the other pusher seeds side by side (PUSHER_SEEDS, default "1 2"; at
#                                            most 3.5 minutes), then, alone and while time is left, learner_speed (CUDA
#                                            graphs, compiled) and loop_speed at 4 envs stepped in turn and in worker
#                                            processes; all comes back in 5 files
#   bash bench/gpu_check.sh table MINUTES    the seeds table: bench/seeds.py for each task in TASKS (default all three)
#                                            over SEEDS (default "0-4"), every run side by side, each stopped at its
#                                            target, its budget or MINUTES (resumable: run it again), rows in
#                                            $OUT/seeds.csv (NOISE=0.1: the noisy oracle's runs instead)
#   bash bench/gpu_check.sh compare MINUTES  the paper's comparison on the pusher: every reward method x seeds 0-2
#                                            side by side, to 15K env steps each (docs/results.md's horizon) or
#                                            MINUTES, then bench/compare.py --by-method (METHODS, SEEDS: fewer)
set -u
phase=${1:-speed}
minutes=${2:-6}
OUT=${OUT:-/tmp/gpu-check}
mkdir -p "$OUT"
python3 -m pip install -q --no-index --no-deps --no-compile --target "$HOME/site" .whl/*.whl || exit 1
export PYTHONPATH="$HOME/site:$PWD"
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
export MUJOCO_GL=egl PYOPENGL_PLATFORM=egl PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$OUT/machine.txt"
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)" | tee -a "$OUT/machine.txt"
nproc | tee -a "$OUT/machine.txt"

if [ "$phase" = speed ]; then
  timeout 330 python3 bench/learner_speed.py --device cuda --compile --updates 500 --blocks 2 2>&1 | tee "$OUT/learner_speed.txt"
  for envs in 1 4; do
    timeout 150 python3 bench/loop_speed.py --device cuda --steps 3000 --envs "$envs" 2>&1 | tee -a "$OUT/loop_speed.txt"
  done
  exit 0
fi

if [ "$phase" = loop ]; then
  timeout 75 python3 bench/loop_speed.py --device cuda --steps 3000 --envs 4 2>&1 | tee "$OUT/loop_speed.txt"
  timeout 120 python3 bench/loop_speed.py --device cuda --steps 3000 --envs 4 --set compile_updates=true 2>&1 \
    | tee -a "$OUT/loop_speed.txt"
  exit 0
fi

runs=bench/out/gpu
logs=$runs/logs  # each bench/learn.py's own output (the device tool brings back at most 8 files: they go in the archive)
mkdir -p "$logs"
collect() {  # what comes back: each run's curve, summary, progress and the end of its learner log, in one archive
  for run in "$runs"/*/; do [ -f "$run/learn.log" ] && tail -n 40 "$run/learn.log" > "$run/learn-tail.log"; done
  tar czf "$OUT/runs.tar.gz" "$runs"/*/curve.csv "$runs"/*/curve.png "$runs"/*/summary.json "$runs"/*/learn-tail.log \
    "$logs"/*.txt
  for log in "$logs"/*.txt; do echo "== $log"; tail -n 2 "$log"; done | tee -a "$OUT/learn.txt"
}
device=${DEVICE:-cuda}  # (DEVICE=cpu with replay_pipeline=device tries a phase on a machine without a GPU)
learn_run() {  # TASK SEED MINUTES: VICE-RAQ in the background with the settings the task was measured to learn with
  local task=$1 seed=$2 steps
  local extra=(--set device="$device" replay_pipeline=device)
  case $task in
    pusher) steps=100000; extra=(--stop-at-success 0.9 "${extra[@]}" num_envs=4) ;;  # (4 envs: measured on the H100)
    door) steps=200000 ;;
    picker) steps=300000 ;;
  esac
  python3 bench/learn.py --task "$task" --algorithm vice_raq --task-settings --seed "$seed" --max-minutes "$3" \
    --threads 2 --total-steps "$steps" "${extra[@]}" --out "$runs/$task-vice_raq-seed$seed" > "$logs/$task-seed$seed.txt" 2>&1 &
}
if [ "$phase" = all ]; then
  deadline=$((SECONDS + ${2:-540}))  # (bash's SECONDS counts from the script's start, the install included)
  left() { echo $((deadline - SECONDS)); }
  learn_run pusher 0 "${PUSHER_ALONE_MINUTES:-3.5}"  # alone: the pusher's time to 90% with the machine to itself
  wait
  # the other pusher seeds side by side, leaving SPEED_RESERVE seconds for the speed figures and packing
  minutes=$(python3 -c "print(max(1.0, min(3.5, ($(left) - ${SPEED_RESERVE:-230}) / 60)))")
  echo "pusher seeds ${PUSHER_SEEDS:-1 2} side by side for at most $minutes minutes" | tee "$OUT/learn.txt"
  for seed in ${PUSHER_SEEDS:-1 2}; do learn_run pusher "$seed" "$minutes"; done
  wait
  collect
  # speed, each alone on the machine while time is left: the update (CUDA graphs, and compiled), then the whole loop
  # at 4 envs stepped in turn and in worker processes
  if [ "$(left)" -gt 100 ]; then
    timeout $(($(left) - 60)) python3 bench/learner_speed.py --device "$device" --graphs-only --compile --updates 500 \
      2>&1 | tee "$OUT/learner_speed.txt"
  fi
  for processes in false true; do
    [ "$(left)" -gt 40 ] || break
    timeout $(($(left) - 15)) python3 bench/loop_speed.py --device "$device" --steps 3000 --envs 4 \
      --set env_processes=$processes 2>&1 | tee -a "$OUT/loop_speed.txt"
  done
  exit 0
fi

if [ "$phase" = pusher ]; then
  for seed in ${SEEDS:-3 4 5}; do learn_run pusher "$seed" "$minutes"; done
  wait
  collect
  exit 0
fi

if [ "$phase" = door-sweep ]; then
  for steps in 5 10 100; do
    for lr in 1e-4 3e-4; do
      python3 bench/learn.py --task door --algorithm vice_raq --seed 0 --max-minutes "$minutes" --total-steps 200000 \
        --query-every 10000 --query-budget 20 --set device="$device" replay_pipeline=device num_envs=4 \
        classifier_steps=$steps classifier_lr=$lr --out "$runs/door-c${steps}-lr${lr}" > "$logs/door-c${steps}-lr${lr}.txt" 2>&1 &
    done
  done
  for steps in 5 10; do
    python3 bench/learn.py --task door --algorithm vice_raq --seed 0 --max-minutes "$minutes" --total-steps 200000 \
      --query-every 1000 --query-budget 300 --set device="$device" replay_pipeline=device num_envs=4 \
      classifier_steps=$steps classifier_lr=3e-4 no_answer_share=0.25 \
      --out "$runs/door-c${steps}-lr3e-4-noanswers" > "$logs/door-c${steps}-lr3e-4-noanswers.txt" 2>&1 &
  done
  wait
  collect
  exit 0
fi

if [ "$phase" = table ]; then
  noise=${NOISE:-0}
  for task in ${TASKS:-pusher door picker}; do
    python3 bench/seeds.py --task "$task" --seeds "${SEEDS:-0-4}" --parallel 5 --threads 1 --noise "$noise" \
      --max-minutes "$minutes" --set device="$device" replay_pipeline=device num_envs=4 \
      --out "$runs/table-noise$noise" --csv "$runs/table-$task-noise$noise.csv" > "$logs/table-$task-noise$noise.txt" 2>&1 &
  done
  wait  # (one CSV per task, as the harnesses write theirs at once; then one file of them all)
  awk 'FNR > 1 || NR == 1' "$runs"/table-*-noise"$noise".csv > "$OUT/seeds.csv"
  tar czf "$OUT/table.tar.gz" --exclude=data "$runs/table-noise$noise" "$logs"/table-*.txt
  cat "$logs"/table-*.txt | tee "$OUT/table.txt"
  exit 0
fi

if [ "$phase" = compare ]; then
  methods=${METHODS:-$(python3 -c "from contract.algorithms import ALGORITHMS; print(*ALGORITHMS)")}
  compared=()  # exactly this phase's runs (not the learn phase's pusher run, stopped at its first 90%)
  for method in $methods; do
    for seed in ${SEEDS:-0 1 2}; do
      compared+=("$runs/compare/pusher-$method-seed$seed")
      python3 bench/learn.py --task pusher --algorithm "$method" --task-settings --seed "$seed" \
        --max-minutes "$minutes" --total-steps 15000 --set device="$device" replay_pipeline=device \
        --out "$runs/compare/pusher-$method-seed$seed" > "$logs/pusher-$method-seed$seed.txt" 2>&1 &
    done
  done
  wait
  for run in "${compared[@]}"; do tail -n 40 "$run/learn.log" > "$run/learn-tail.log" 2>/dev/null; done
  tar czf "$OUT/compare.tar.gz" "$runs"/compare/*/curve.csv "$runs"/compare/*/summary.json "$runs"/compare/*/learn-tail.log \
    "$logs"/pusher-*.txt
  python3 bench/compare.py --by-method --until 15000 "${compared[@]}" --out "$OUT/pusher-methods.png" \
    --title "pusher: eval success, mean and min-max over seeds" | tee "$OUT/pusher-methods.md"
  exit 0
fi

# learn: the three tasks side by side for each seed in SEEDS (default 0), with the settings each task was measured to
# learn with (bench/learn.py --task-settings), each stopped after MINUTES (the pusher at its first 90% evaluation)
for seed in ${SEEDS:-0}; do
  for task in pusher door picker; do learn_run "$task" "$seed" "$minutes"; done
done
wait
collect
