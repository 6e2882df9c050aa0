#!/bin/bash
# S-Flow of umf-small-bandai-20261207 fine-tuned with the real takes half of every batch
# (real_repeats 300 beside 3,000 composed scenes). Resumable: run again with --resume.
cd /work/main
exec nice .venv/bin/umf train finetune --from src/umf/assets/model \
  --corpus ~/umf-runs/full/corpus --out ~/umf-runs/salsa-sf/run --stages sflow "$@" \
  --set train_sflow.max_steps=1500 --set train_sflow.lr=0.0001 --set train_sflow.real_repeats=300 \
  --set train_sflow.val_every=500 --set train_sflow.ckpt_every=100
