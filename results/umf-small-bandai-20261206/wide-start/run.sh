#!/bin/bash
# Issue 38: the S-Flow's reaction half starts from C + 1.0 eps' (a full-width start, as the
# P-Flow's) with the context beside the state (sflow.context_condition). From 20261204b.
cd /work/main
exec nice .venv/bin/umf train finetune --from bundled --corpus ~/umf-runs/full/corpus \
  --out ~/umf-runs/wide/run --stages sflow --no-progress "$@" \
  --set sflow.context_condition=true --set sflow.reaction_noise=1.0 \
  --set train_sflow.max_steps=5000 --set train_sflow.lr=0.0003 --set train_sflow.warmup_steps=100 \
  --set train_sflow.real_repeats=60 --set train_sflow.val_every=1000 --set train_sflow.ckpt_every=100
