#!/bin/bash
# Issue 34, round 4: 20261204b's flows on a corpus with twice the composed scenes (full13:
# 6,000 train scenes, 462 of them stand_facing), the S-Flow reading own prompts through a
# text head of its own (sflow.denoiser.person_head). Resumable: run again with --resume.
cd /work/main
echo -10 > /proc/$$/autogroup 2>/dev/null
exec nice .venv/bin/umf train finetune --from src/umf/assets/model \
  --corpus ~/umf-runs/full13/corpus --out ~/umf-runs/head/run --stages pflow,sflow "$@" \
  --set sflow.denoiser.person_head=true \
  --set train_pflow.max_steps=800 --set train_pflow.lr=0.0002 --set train_pflow.real_repeats=60 \
  --set train_pflow.relation_repeats=[stand_facing=8] \
  --set train_pflow.val_every=400 --set train_pflow.ckpt_every=50 \
  --set train_sflow.max_steps=3000 --set train_sflow.lr=0.0003 --set train_sflow.real_repeats=60 \
  --set train_sflow.relation_repeats=[stand_facing=8] \
  --set train_sflow.val_every=1000 --set train_sflow.ckpt_every=100
