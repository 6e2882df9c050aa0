#!/usr/bin/env bash
# The paper's ablations (Tables 3-5) on our corpus, with the `small` configuration.
#
#   scripts/ablations.sh RUN CORPUS [OUT]
#
# RUN is the finished `umf train all --family small` run of the model under study (the
# bundled model: runs/small), CORPUS its corpus, OUT the results (results/ablations).
# Variants that change one flow reuse RUN's VAE and the other flow; latent-space variants
# need their own VAE, so Table 3 trains three models from scratch at a reduced, matched
# budget (500 steps per stage, baseline included). Two training lanes run side by side
# (one thread each: on a 2-core CPU that beats one lane with two threads). About 1 h 40 min
# of training and 1 h of evaluation on a 2-core CPU.
set -euo pipefail
RUN=${1:?usage: scripts/ablations.sh RUN CORPUS [OUT]}
CORPUS=${2:?usage: scripts/ablations.sh RUN CORPUS [OUT]}
OUT=${3:-results/ablations}
WORK=${ABLATION_RUNS:-runs/ablations}
UMF=${UMF:-umf}
mkdir -p "$WORK" "$OUT"

from_run() {  # a variant run starting from RUN's config, VAE and the given flow
  mkdir -p "$WORK/$1"
  cp "$RUN/config.yaml" "$WORK/$1/"
  for stage in vae "$2"; do rm -rf "${WORK:?}/$1/$stage"; cp -r "$RUN/$stage" "$WORK/$1/"; done
}
train() {  # stage run [--set ...]: skipped when finished, resumed when killed
  local stage=$1 dir=$WORK/$2 resume=()
  shift 2
  [ -e "$dir/$stage/best" ] && [ -e "$dir/$stage/.done" ] && return
  [ -e "$dir/$stage/last" ] && resume=(--resume)
  "$UMF" train "$stage" --corpus "$CORPUS" --out "$dir" --no-progress "${resume[@]}" "$@"
  touch "$dir/$stage/.done"
}
export_model() { "$UMF" train export --run "$WORK/$1" --out "$WORK/$1/model"; }

flow_lane() {  # Tables 4 and 5: one flow retrained at the full small budget
  from_run no-pyramid sflow
  train pflow no-pyramid --set pflow.num_stages=1 --set 'pflow.steps=[50]'
  export_model no-pyramid
  from_run grid-pyramid sflow
  train pflow grid-pyramid --set pflow.layout=2d
  export_model grid-pyramid
  local name opt
  for name in reaction-only no-recon-loss no-context-adapter shared-backbone; do
    case $name in
      reaction-only) opt=sflow.reaction_only=true ;;
      no-recon-loss) opt=sflow.lambda_recon=0 ;;
      no-context-adapter) opt=sflow.context_adapter=false ;;
      shared-backbone) opt=sflow.shared_backbone=true ;;
    esac
    from_run "$name" pflow
    train sflow "$name" --set "$opt"
    export_model "$name"
  done
}

latent_lane() {  # Table 3: each latent space with its own VAE, 500 steps per stage
  local budget=(--family small --set train_vae.max_steps=500 --set train_pflow.max_steps=500
    --set train_sflow.max_steps=500)
  local name
  for name in multi-token single-token no-latent-adapter; do
    local opts=()
    case $name in
      single-token) opts=(--set vae.num_tokens=1 --set vae.latent_dim=256
        --set pflow.num_stages=1 --set 'pflow.steps=[50]') ;;
      no-latent-adapter) opts=(--set vae.latent_adapter=false) ;;
    esac
    for stage in vae pflow sflow; do train "$stage" "$name" "${budget[@]}" "${opts[@]}"; done
    export_model "$name"
  done
}

OMP_NUM_THREADS=1 flow_lane > "$WORK/flow-lane.log" 2>&1 &
flow=$!
OMP_NUM_THREADS=1 latent_lane > "$WORK/latent-lane.log" 2>&1 &
latent=$!
wait $flow
wait $latent

EVAL=(--corpus "$CORPUS" --replications 3 --mm-prompts 8 --mm-samples 5 --length-step 15
  --no-progress)
MODEL=$RUN/model
"$UMF" eval --checkpoint "$WORK/multi-token/model" --out "$OUT/latent" "${EVAL[@]}" \
  --variant "single-token=$WORK/single-token/model" \
  --variant "no-latent-adapter=$WORK/no-latent-adapter/model"
"$UMF" eval --checkpoint "$MODEL" --out "$OUT/pyramid" "${EVAL[@]}" \
  --variant "steps-25-25=$MODEL:pflow_steps=25,25" \
  --variant "steps-5-5=$MODEL:pflow_steps=5,5" \
  --variant "no-pyramid=$WORK/no-pyramid/model" \
  --variant "grid-pyramid=$WORK/grid-pyramid/model"
"$UMF" eval --checkpoint "$MODEL" --out "$OUT/sflow" "${EVAL[@]}" \
  --variant "reaction-only=$WORK/reaction-only/model" \
  --variant "no-recon-loss=$WORK/no-recon-loss/model" \
  --variant "no-context-adapter=$WORK/no-context-adapter/model" \
  --variant "shared-backbone=$WORK/shared-backbone/model"
python scripts/ablation_tables.py "$OUT" --time
