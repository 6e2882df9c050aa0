"""Where people 2..N stand at the first frame, and how close person k >= 3 comes to anyone
before them: group prompts, seeds 0-3, 4 s, raw (what results/reactions-20261208 quotes).

    python results/reactions-20261208/tried/positions.py > positions.txt
"""

from umf.data.relations import closest_joints, lateral_offset
from umf.pipeline import UMFPipeline

PROMPTS = {
    "Three people walk in single file.": 3,
    "A person bows to two people, who bow back.": 3,
    "Three people stand in a circle and bow.": 3,
    "Three people walk side by side.": 3,
    "A person calls out to three people, who respond.": 4,
}

pipe = UMFPipeline.from_pretrained()
print(f"model {pipe.name}; person k at (metres to person 1's left, ahead), first frame; "
      "closest joints of each person k >= 3 to each earlier person (m)")  # fmt: skip
for prompt, n in PROMPTS.items():
    scenes = pipe([prompt] * 4, num_people=n, seconds=4, seed=0, sample_indices=range(4),
                  fit=False, separate=False)  # fmt: skip
    print(prompt)
    for s in scenes:
        j = s.joints
        at = []
        for k in range(1, n):
            left, ahead = lateral_offset(j, 0, k, 0)
            at.append(f"P{k + 1} ({left:+.2f}, {ahead:+.2f})")
        gaps = [f"P{k + 1}-P{m + 1} {closest_joints(j[k], j[m])[0]:.2f}"
                for k in range(2, n) for m in range(k)]  # fmt: skip
        print("  " + ", ".join(at) + "; closest " + ", ".join(gaps))
