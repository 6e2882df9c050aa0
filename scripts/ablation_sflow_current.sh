#!/usr/bin/env bash
# Table 5's central comparison on a trained model: its S-Flow vs the reaction-only
# (noise-free, ARFlow-style) path, both retrained at the `small` CPU budget on the model's
# own VAE and P-Flow, then scored by `umf eval --quick` (the first person is shared).
#
#   scripts/ablation_sflow_current.sh MODEL_DIR CORPUS [WORK] [OUT]
#
# About 25 min of training (two S-Flows, 500 steps of batch 128, one thread each) and 8 min
# of evaluation on a 2-core CPU. Resumable: finished stages are skipped, killed ones resume.
set -euo pipefail
MODEL=${1:?usage: scripts/ablation_sflow_current.sh MODEL_DIR CORPUS [WORK] [OUT]}
CORPUS=${2:?usage: scripts/ablation_sflow_current.sh MODEL_DIR CORPUS [WORK] [OUT]}
WORK=${3:-runs/ablation-sflow}
OUT=${4:-results/ablations/sflow-current}
UMF=${UMF:-umf}
PY=${PYTHON:-python}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}

for v in s-flow-500 reaction-only-500; do
  d=$WORK/$v
  if [ ! -e "$d/config.yaml" ]; then  # the model's config, with the small family's S-Flow budget
    mkdir -p "$d"
    "$PY" - "$MODEL" "$d" <<'EOF'
import dataclasses, shutil, sys
from pathlib import Path
from umf.config import UMFConfig, family_config
model, run = Path(sys.argv[1]), Path(sys.argv[2])
cfg = UMFConfig.load_yaml(model / "config.json")
cfg = dataclasses.replace(cfg, train_sflow=family_config("small").train_sflow)
cfg.save_yaml(run / "config.yaml")
for stage in ("vae", "pflow"):
    shutil.copytree(model, run / stage / "best", dirs_exist_ok=True)
EOF
  fi
  opt=()
  [ "$v" = reaction-only-500 ] && opt=(--set sflow.reaction_only=true)
  if [ ! -e "$d/sflow/.done" ]; then
    resume=()
    [ -e "$d/sflow/last" ] && resume=(--resume)
    "$UMF" train sflow --corpus "$CORPUS" --out "$d" --no-progress "${resume[@]}" "${opt[@]}"
    touch "$d/sflow/.done"
  fi
  if [ ! -e "$d/model/format.json" ]; then
    "$UMF" train export --run "$d" --out "$d/model"
    "$PY" -c "import json,sys; p=sys.argv[1]; f=json.load(open(p)); f['name']=sys.argv[2]; json.dump(f, open(p, 'w'), indent=2)" "$d/model/format.json" "$v"
  fi
done
"$UMF" eval --checkpoint "$WORK/s-flow-500/model" --corpus "$CORPUS" --out "$OUT" --quick \
  --no-progress --variant "reaction-only-500=$WORK/reaction-only-500/model"
