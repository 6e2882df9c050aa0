#!/usr/bin/env bash
# The paper's ablations (Tables 3-5) on a trained model, at the `small` family's CPU budget.
#
#   research/ablations.sh MODEL CORPUS [OUT]
#
# MODEL is the model under study (the bundled one: src/umf/assets/model), CORPUS its corpus,
# OUT the reports (results/ablations). Every row, the baseline included, retrains what it
# varies at one budget (the small family's: P-Flow 1,000 steps of batch 128, S-Flow 500 of
# batch 128), so the rows compare with each other, not with MODEL's own longer training.
# Tables 4 (P-Flow) and 5 (S-Flow) keep MODEL's VAE and the flow they do not vary. Table 3
# (latent space) trains a VAE and both flows per row and is not run unless TABLES names it
# (TABLES="3 4 5"; about 85 min of one CPU thread per row).
#
# Two training lanes run side by side, one thread each (on a 2-core CPU that beats one lane
# of two threads), then the reports, also side by side on one thread each; Tables 4-5 take
# about 1 h of training and 40 min of evaluation here.
# Resumable: finished stages and written reports are skipped, killed stages resume.
set -euo pipefail
MODEL=${1:?usage: research/ablations.sh MODEL CORPUS [OUT]}
CORPUS=${2:?usage: research/ablations.sh MODEL CORPUS [OUT]}
OUT=${3:-results/ablations}
WORK=${ABLATION_RUNS:-runs/ablations}
TABLES=${TABLES:-4 5}
UMF=${UMF:-umf}
PY=${PYTHON:-python}
mkdir -p "$WORK" "$OUT"

prepare() {  # NAME "KEEP STAGES" [--set OPT ...]: the run's config.yaml (MODEL's config at
  # the small budget, with the variant's options: right even when a finished stage is not
  # retrained) and MODEL's weights for the stages kept
  local name=$1 keep=$2
  shift 2
  [ -e "$WORK/$name/config.yaml" ] && return
  mkdir -p "$WORK/$name"
  "$PY" - "$MODEL" "$WORK/$name" "$keep" "$@" <<'EOF'
import dataclasses, shutil, sys
from pathlib import Path
from umf.config import UMFConfig, family_config, set_option
model, run, keep = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3].split()
cfg = UMFConfig.load_yaml(model / "config.json")
small = family_config("small")
cfg = dataclasses.replace(cfg, train_vae=small.train_vae, train_pflow=small.train_pflow,
                          train_sflow=small.train_sflow)
for opt in sys.argv[5::2]:  # the values of "--set OPT" pairs
    cfg = set_option(cfg, opt)
for stage in keep:
    shutil.copytree(model, run / stage / "best", dirs_exist_ok=True)
cfg.save_yaml(run / "config.yaml")
EOF
}
train() {  # STAGE NAME: on the run's config.yaml; skipped when finished, resumed when killed
  local stage=$1 dir=$WORK/$2 resume=()
  [ -e "$dir/$stage/.done" ] && return
  [ -e "$dir/$stage/last" ] && resume=(--resume)
  "$UMF" train "$stage" --corpus "$CORPUS" --out "$dir" --no-progress "${resume[@]}"
  touch "$dir/$stage/.done"
}
export_model() {  # NAME: the run's model directory, named for the variant in reports
  [ -e "$WORK/$1/model/format.json" ] && return
  "$UMF" train export --run "$WORK/$1" --out "$WORK/$1/model"
  "$PY" -c "import json,sys; p=sys.argv[1]; f=json.load(open(p)); f['name']=sys.argv[2]; json.dump(f, open(p, 'w'), indent=2)" \
    "$WORK/$1/model/format.json" "$1"
}
flow_variant() {  # NAME STAGE [--set ...]: retrain STAGE (pflow or sflow), keep the rest
  local name=$1 stage=$2
  shift 2
  if [ "$stage" = pflow ]; then prepare "$name" "vae sflow" "$@"; else prepare "$name" "vae pflow" "$@"; fi
  train "$stage" "$name"
  export_model "$name"
}
latent_variant() {  # NAME [--set ...]: a VAE and both flows
  local name=$1 stage
  shift
  prepare "$name" "" "$@"
  for stage in vae pflow sflow; do train "$stage" "$name"; done
  export_model "$name"
}
has() { [[ " $TABLES " == *" $1 "* ]]; }

lane_a() {
  if has 4; then
    flow_variant p-flow pflow
    flow_variant no-pyramid pflow --set pflow.num_stages=1 --set 'pflow.steps=[50]'
  fi
  if has 3; then
    latent_variant multi-token
    latent_variant single-token --set vae.num_tokens=1 --set vae.latent_dim=256 \
      --set vae.aligned_tokens=false --set pflow.num_stages=1 --set 'pflow.steps=[50]'
  fi
}
lane_b() {
  if has 5; then
    flow_variant s-flow sflow
    flow_variant reaction-only sflow --set sflow.reaction_only=true
    flow_variant no-recon-loss sflow --set sflow.lambda_recon=0
    flow_variant no-context-adapter sflow --set sflow.context_adapter=false
    flow_variant shared-backbone sflow --set sflow.shared_backbone=true
  fi
  if has 4; then flow_variant grid-pyramid pflow --set pflow.layout=2d; fi
  if has 3; then latent_variant no-latent-adapter --set vae.latent_adapter=false; fi
}

OMP_NUM_THREADS=1 lane_a > "$WORK/lane-a.log" 2>&1 &
a=$!
OMP_NUM_THREADS=1 lane_b > "$WORK/lane-b.log" 2>&1 &
b=$!
wait $a
wait $b

EVAL=(--corpus "$CORPUS" --replications 3 --mm-prompts 8 --mm-samples 5 --length-step 15
  --no-progress)
evaluate() {  # OUT_DIR MODEL [--variant ...]: one report (one thread), skipped when written
  local out=$1 model=$2
  shift 2
  [ -e "$out/metrics.json" ] && return
  OMP_NUM_THREADS=1 "$UMF" eval --checkpoint "$model" --out "$out" "${EVAL[@]}" "$@" \
    > "$WORK/eval-$(basename "$out").log" 2>&1
}
reports=()  # the reports run side by side, like the training lanes
if has 3; then
  evaluate "$OUT/latent" "$WORK/multi-token/model" \
    --variant "single-token=$WORK/single-token/model" \
    --variant "no-latent-adapter=$WORK/no-latent-adapter/model" &
  reports+=($!)
fi
if has 4; then
  P=$WORK/p-flow/model
  evaluate "$OUT/pyramid" "$P" \
    --variant "steps-25-25=$P:pflow_steps=25,25" \
    --variant "steps-5-5=$P:pflow_steps=5,5" \
    --variant "no-pyramid=$WORK/no-pyramid/model" \
    --variant "grid-pyramid=$WORK/grid-pyramid/model" &
  reports+=($!)
fi
if has 5; then
  evaluate "$OUT/sflow" "$WORK/s-flow/model" \
    --variant "reaction-only=$WORK/reaction-only/model" \
    --variant "no-recon-loss=$WORK/no-recon-loss/model" \
    --variant "no-context-adapter=$WORK/no-context-adapter/model" \
    --variant "shared-backbone=$WORK/shared-backbone/model" &
  reports+=($!)
fi
for r in "${reports[@]}"; do wait "$r"; done
"$PY" research/ablation_tables.py "$OUT" --time
