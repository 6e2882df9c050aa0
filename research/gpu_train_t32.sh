#!/usr/bin/env bash
# The 32-token model on one lent GPU, in two calls of the device tool (what one call may
# carry is capped: the motion pack and the text features travel apart), on the same warm
# machine:
#   call 1 (carry .gpu/pack):  research/gpu_train_t32.sh vae   BUDGET_S   # unpack motion, train the VAE
#   call 2 (carry .gpu/text):  research/gpu_train_t32.sh flows BUDGET_S   # unpack text, train both flows
# Both calls pass the same options, so the flows load the VAE they were planned with.
# With a VAE already trained (a model directory holding vae.safetensors, config.json and
# normalizer.safetensors), call 1 is `motion` (unpack only) and call 2 carries that directory
# too and names it: VAE_MODEL=.gpu/t32-vae research/gpu_train_t32.sh flows BUDGET_S.
# The VAE's options then come from that directory's config.json (the vae.* options below are
# not applied), so the same call retrains the flows of any model, e.g. the bundled 16-token
# one: VAE_MODEL=src/umf/assets/model FLOW_STEPS=7000 research/gpu_train_t32.sh flows 565
# (results/flows-long-h200-20261126: 8,600 planned, 7,000-7,750 reached in 575 s on an H200).
# A model trained with `vae` samples pairs at the S-Flow's 10 steps (the small family's): choose
# sflow.pair_steps on the val split afterwards (umf eval --split val --variant
# NAME=DIR:sflow_steps=3), as the bundled model's 4 were chosen; with VAE_MODEL the carried
# model's sampling settings (pair_steps included) are kept. The training options below (lr,
# batch, EMA, latent passes, guidance 2) apply in both cases.
# Packs: python scripts/corpus_pack.py pack out/corpus .gpu/pack coarse (then text.npz, int8
# features: 14 MB, to .gpu/text).
# When the working tree plus a pack exceed one call's carry (64 MiB; the tree alone is 43 MB,
# the coarse motion pack 26 MB), split the packs into parts and stash all but the last on the
# warm machine: `python scripts/corpus_pack.py split .gpu/all .gpu 2`, then
#   call 1 (carry .gpu/part1):  research/gpu_train_t32.sh stash
#   call 2 (carry .gpu/part2):  research/gpu_train_t32.sh flows BUDGET_S   # (or vae / motion)
# A phase that carries a part joins it with the stashed ones (SHA-256 checked) and unpacks
# them instead of .gpu/pack or .gpu/text (results/umf-small-bandai-h200-20261127).
set -euo pipefail
phase=${1:-} budget=${2:-}
export PYTHONPATH=$PWD/src PYTHONUNBUFFERED=1 RUNS=${RUNS:-$PWD/out/runs} CORPUS=${CORPUS:-out/corpus}
VAE_OPTS=(
  --set vae.num_tokens=32 --set vae.token_span=5.0
  --set train_vae.max_steps=2000 --set train_vae.batch_size=128 --set train_vae.warmup_steps=300
  --set train_vae.val_every=1000 --set train_vae.ckpt_every=1000 --set train_vae.log_every=25
  --set train_vae.hold_rest=true --set train_vae.repeat_gait=true
)
[ -n "${VAE_MODEL:-}" ] && VAE_OPTS=()  # a carried VAE brings its own options
OPTS=(
  ${VAE_OPTS[@]+"${VAE_OPTS[@]}"}  # (empty-safe under set -u on old bash too)
  --set pflow.guidance=2.0 --set sflow.guidance=2.0
  # short clips extended to whole crops, both spellings of direction words (the bundled
  # model's fine-tunes: results/umf-small-bandai-20261127b)
  --set train_pflow.hold_rest=true --set train_pflow.repeat_gait=true
  --set train_pflow.respell_captions=true
  --set train_pflow.max_steps=${FLOW_STEPS:-5000} --set train_sflow.max_steps=${FLOW_STEPS:-5000}
  --set train_pflow.batch_size=512 --set train_sflow.batch_size=512
  --set train_pflow.lr=0.0004 --set train_sflow.lr=0.0004
  --set train_pflow.warmup_steps=300 --set train_sflow.warmup_steps=300
  --set train_pflow.ema_decay=0.999 --set train_sflow.ema_decay=0.999
  --set train_pflow.latent_passes=6 --set train_sflow.latent_passes=8
  --set train_pflow.val_every=400 --set train_sflow.val_every=400
  --set train_pflow.ckpt_every=400 --set train_sflow.ckpt_every=400
)
OPTS+=(${EXTRA:-})  # dry runs: fewer steps
STASH=${STASH:-/tmp/umf-stash}
unpack() {  # the carried pack ($1), or, when this call carries a part, it and the stashed ones
  shopt -s nullglob
  local carried=(.gpu/part*) stashed=("$STASH"/part*)
  shopt -u nullglob
  if [ ${#carried[@]} -gt 0 ]; then
    rm -rf .gpu/joined
    python scripts/corpus_pack.py join .gpu/joined ${stashed[@]+"${stashed[@]}"} "${carried[@]}"
    python scripts/corpus_pack.py unpack .gpu/joined "$CORPUS"
    # used once: a later call on this warm machine that carries no part must not find them
    rm -rf "$STASH" "${carried[@]}" .gpu/joined
  else
    python scripts/corpus_pack.py unpack "$1" "$CORPUS"
  fi
}
case $phase in
  stash)
    mkdir -p "$STASH" && cp -r .gpu/part* "$STASH"/ && ls -l "$STASH"/* ;;
  motion)
    unpack .gpu/pack ;;
  vae)
    unpack .gpu/pack
    VAE_WORKERS=${VAE_WORKERS:-12} python scripts/gpu_flows_train.py "$budget" --vae-only "${OPTS[@]}" ;;
  flows)
    unpack .gpu/text
    rc=0
    if [ -n "${VAE_MODEL:-}" ]; then vae=(); export MODEL=$VAE_MODEL; else vae=(--vae); fi
    PFLOW_WORKERS=${PFLOW_WORKERS:-9} SFLOW_WORKERS=${SFLOW_WORKERS:-5} \
      python scripts/gpu_flows_train.py "$budget" "${vae[@]}" "${OPTS[@]}" || rc=$?
    # at most 8 files come back: the model's six, and one archive of logs and metrics
    cd "$OUT" && shopt -s nullglob && logs=(./*.log ./*-metrics.csv ./plan.yaml)
    [ ${#logs[@]} -eq 0 ] || tar czf training.tgz --remove-files "${logs[@]}" || true
    rm -f best-*.safetensors
    exit $rc ;;
  *) echo "usage: $0 stash|motion|vae|flows BUDGET_S" >&2; exit 2 ;;
esac
