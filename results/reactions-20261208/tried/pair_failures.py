"""Val pairs of some relations one by one, raw as the protocol generates them: where person 2
starts and ends in person 1's frame, the closest joints, and each failed check's value (for a
bow back, how many frames after person 1's bow person 2's starts).

    python results/reactions-20261208/tried/pair_failures.py CORPUS bow_back [key=value ...]
"""

import json
import sys

from umf.data.corpus import Corpus
from umf.data.relations import check_record, closest_joints, lateral_offset
from umf.eval.contenders import load_contenders
from umf.eval.plan import make_plan
from umf.eval.report import _joints_contacts, generate_records
from umf.pipeline import default_model_dir

corpus = Corpus.load(sys.argv[1])
wanted = sys.argv[2].split(",")
records = [r for r in corpus.scenes["val"] if r["relation"] in wanted]
plan = make_plan(length_step=15)
(c,) = load_contenders(default_model_dir(), [], "cpu", plan, progress=False)
for item in sys.argv[3:]:
    key, value = item.split("=", 1)
    setattr(c.pipe.config.sflow, key, json.loads(value))
both = generate_records(c, records, plan.seed + 200_000, _joints_contacts)
for r, (j, _) in zip(records, both, strict=True):
    start, end = lateral_offset(j, 0, 1, 0), lateral_offset(j, 0, 1, j.shape[1] - 1)
    d, t, _ = closest_joints(j[0], j[1])
    fails = [f"{x.type} {x.value:.2f}" for x in check_record(j, r) if not x.passed]
    need = [x["min_frames"] for x in r["constraints"] if x["type"] == "starts_after"]
    print(f"{r['relation']} T={j.shape[1]} start ({start[0]:+.2f}, {start[1]:+.2f}) end "
          f"({end[0]:+.2f}, {end[1]:+.2f}) closest {d:.2f} m at {t}"
          + (f"; starts_after needs {need[0]}" if need else "")
          + f"; failed: {', '.join(fails) or '-'}")  # fmt: skip
