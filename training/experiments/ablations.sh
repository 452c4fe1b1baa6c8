#!/usr/bin/env bash
# Ablations in the paper's spirit (Danceba Tables 2-3) on the tempo-normalised data. CPU budget does not
# allow several from-scratch trainings here (a from-scratch model needs ~700 iterations to leave the
# uniform-loss plateau), so every variant is fine-tuned from the same parent (the shipped model before
# this fine-tuning, or any .dncw) for the same number of iterations, the removed part dropped and
# everything else copied: full (control), no PRE, no gate, one shared Mamba, reactive (music shift 1).
# Each is exported and measured with the engine (tempo following, seeds pooled) and the teacher-forced
# validation losses (music gap).
#   training/experiments/ablations.sh PARENT.dncw [ITERS [VARIANT...]]   (default 200 and all variants; run from anywhere;
#                                                             .venv for metrics)
# VARIANT: full, no_pre, no_gate, shared_mamba, reactive.
# Results: training/runs/abl_<name>/{train.log,eval_report.json,engine_tempo.json,engine/metrics.md}
# A run directory that exists is resumed if it was made from the same parent (its parent.sha256), else the
# script stops: remove training/runs/abl_* to start over with another parent.
set -euo pipefail
parent="$(realpath "${1:?usage: training/experiments/ablations.sh PARENT.dncw [ITERS [VARIANT...]]}")"
cd "$(dirname "$0")/../.."
iters="${2:-200}"
shift $(( $# < 2 ? $# : 2 ))
wanted=("$@")
for w in "${wanted[@]}"; do
  case "$w" in full|no_pre|no_gate|shared_mamba|reactive) ;;
    *) echo "ablations.sh: unknown variant '$w' (full, no_pre, no_gate, shared_mamba, reactive)" >&2; exit 2 ;;
  esac
done
py="${PYTHON:-.venv/bin/python}"
# Tokens are cached per parent (its VQ-VAEs make them): a cache made with another parent would be wrong.
parent_sha="$(sha256sum "$parent" | cut -d' ' -f1)"
tokens="training/runs/ablation_tokens_${parent_sha:0:12}"
export OMP_WAIT_POLICY=PASSIVE
for spec in "full:" "no_pre:--no-pre" "no_gate:--no-gate" "shared_mamba:--shared-mamba" "reactive:--lookahead 1"; do
  name="${spec%%:*}"
  flags="${spec#*:}"
  if (( ${#wanted[@]} )) && [[ ! " ${wanted[*]} " == *" ${name} "* ]]; then continue; fi
  run="training/runs/abl_${name}"
  if [[ -d "$run" && "$(cat "$run/parent.sha256" 2>/dev/null)" != "$parent_sha" ]]; then
    echo "ablations.sh: $run was made from another parent (or before parents were recorded); remove it" >&2
    exit 2
  fi
  mkdir -p "$run"
  echo "$parent_sha" > "$run/parent.sha256"
  # shellcheck disable=SC2086
  "$py" -m training.train --run "$run" --stages seq,export,eval --vq-model "$parent" --init-model "$parent" \
    --vq-run "$tokens" --seq-iters "$iters" --lr 3e-4 --val-every 100 \
    --out "$run/model.dncw" $flags
done
