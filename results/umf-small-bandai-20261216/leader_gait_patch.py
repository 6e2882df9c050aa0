"""Fine-tune the bundled P-Flow with each short composed scene whose person 1 ends in a
steady, straight gait served at a full crop: person 1's last cycle repeated (the P-Flow
learns person 1 only; the others are held at their last frame, which it never reads).

    python leader_gait.py CORPUS RUN [finetune options...]
"""
import sys

import umf.train.datasets as D
from umf.data.extension import gait_period

real_init = D.SceneDataset.__init__


def init(self, corpus, split, normalizer, *args, repeat_gait=False, **kw):
    real_init(self, corpus, split, normalizer, *args, repeat_gait=repeat_gait, **kw)
    short = {r["id"]: r for kind, r, _ in self.items
             if kind == "scene" and r["num_frames"] - 1 < self.min_frames}
    n = 0
    for sid, r in short.items():
        if sid in self.extended:
            continue
        j = corpus.scene_joints(r)
        p = gait_period(j[0])
        if p and r.get("relation") not in ("walk_toward",):
            self.extended[sid] = [p] + [0] * (j.shape[0] - 1)
            n += 1
    print(f"[leader gait] {split}: {n} scenes carried on by person 1's gait", file=sys.stderr)


D.SceneDataset.__init__ = init
from umf.cli.main import run  # noqa: E402

corpus, out, *rest = sys.argv[1:]
sys.argv = ["umf", "train", "finetune", "--from", "src/umf/assets/model", "--corpus", corpus,
            "--out", out, "--stages", "pflow", *rest]
run()
