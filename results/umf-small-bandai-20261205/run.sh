#!/bin/bash
# Issue 38: the S-Flow reads its context beside the state (sflow.context_condition, a
# zero-initialised projection: it starts as the bundled model) and starts its reaction half
# from C + 0.5 eps' instead of C + 0.125 eps' (sflow.reaction_noise): a start wide enough
# to sample one reaction rather than the average one, with the context still clear.
# From the bundled 20261204b on its own corpus (full12). Resumable: run again with --resume.
cd /work/main
echo -10 > /proc/$$/autogroup 2>/dev/null
exec nice .venv/bin/umf train finetune --from bundled --corpus ~/umf-runs/full12/corpus \
  --out ~/umf-runs/ctx/run --stages sflow "$@" \
  --set sflow.context_condition=true --set sflow.reaction_noise=0.5 \
  --set train_sflow.max_steps=3600 --set train_sflow.lr=0.0002 --set train_sflow.real_repeats=60 \
  --set train_sflow.val_every=600 --set train_sflow.ckpt_every=100
