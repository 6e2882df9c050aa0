"""Render the README's examples with the bundled model: PNG strips of generated frames.

Each example is exactly what its `umf generate` command (printed, and listed in the
README) produces: same prompt, people, duration and seed. Writes
``docs/images/generated/<name>.png``. Five frames a second apart cannot show a wave's
swing, so the wave also gets a close strip (``wave_front.png``): the same person seen from
the front (its heading at frame 0), every 0.2 s from 0.4 s to 1.8 s.

    python scripts/readme_examples.py [--model DIR] [--out docs/images/generated]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

EXAMPLES = [
    # (file name, prompt, people, seconds): wordings the training captions use
    ("walk", "A person walks forward.", 1, 4.0),
    ("wave", "Someone waves with the right hand.", 1, 4.0),
    ("raise_hands", "A person raises both hands.", 1, 4.0),
    ("bow", "Someone bows politely.", 1, 4.0),
    ("run", "A person runs forward.", 1, 4.0),
    ("bow_back", "One person bows and the other bows back.", 2, 4.0),
    ("walk_side_by_side", "Two people walk side by side.", 2, 4.0),
    ("step_back", "One person kicks and the other steps back.", 2, 4.0),
    ("call_approach", "One person calls out and the other walks over to them.", 2, 4.0),
    ("group_line", "Three people walk side by side.", 3, 4.0),
    ("gather", "A person calls and four people walk over to them.", 5, 4.0),
    ("salsa", "Two people dance salsa together.", 2, 4.0),  # real CMU takes
    ("backflip", "A person does a backflip.", 1, 4.0),  # DeepMimic
    ("crawl", "A person crawls on hands and knees.", 1, 4.0),
    ("getup", "A person lying face down gets up.", 1, 4.0),  # DeepMimic, eased to a stop
]
# (file name, scene prompt, people, seconds, person prompts): `--person` for each, in order;
# drawn only by a model with per-person prompts
PERSON_EXAMPLES = [
    ("facing_hands_bow", "Two people stand facing each other.", 2, 4.0,
     ["A person raises both hands.", "Someone bows politely."]),
    ("facing_bow_hands", "Two people stand facing each other.", 2, 4.0,
     ["Someone bows politely.", "A person raises both hands."]),
]  # fmt: skip
FRAMES = 5  # evenly spaced frames per strip
# (file name, the example re-rolled, its person, the re-roll's seed): `umf reroll`
REROLLS = [("group_line_reroll_p2", "group_line", 2, 7)]
# (file name, example it shows again, frames): close strips seen from the front
CLOSE = [("wave_front", "wave", list(range(12, 55, 6)))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("docs/images/generated"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    from umf.eval.motion_stats import start_facing
    from umf.pipeline import UMFPipeline
    from umf.render import save_still

    pipe = UMFPipeline.from_pretrained(args.model)
    args.out.mkdir(parents=True, exist_ok=True)
    scenes = {}
    for name, prompt, people, seconds in EXAMPLES:
        scene = scenes[name] = pipe(prompt, num_people=people, seconds=seconds, seed=args.seed)[0]
        t = scene.num_frames
        frames = [round(i * (t - 1) / (FRAMES - 1)) for i in range(FRAMES)]
        path = save_still(scene.joints, args.out / f"{name}.png", frames, caption=prompt)
        print(f'{path}: umf generate "{prompt}" --people {people} --seconds {seconds:g} '
              f"--seed {args.seed} --format gif")  # fmt: skip
    for name, prompt, people, seconds, own in PERSON_EXAMPLES if pipe.person_prompts else ():
        scene = scenes[name] = pipe(prompt, num_people=people, seconds=seconds, seed=args.seed,
                                    person_prompts=own)[0]  # fmt: skip
        t = scene.num_frames
        frames = [round(i * (t - 1) / (FRAMES - 1)) for i in range(FRAMES)]
        said = "; ".join(f"P{k} {p.rstrip('.').lower()}" for k, p in enumerate(own, 1))
        path = save_still(scene.joints, args.out / f"{name}.png", frames,
                          caption=f"{prompt} ({said})")  # fmt: skip
        flags = " ".join(f'--person "{p}"' for p in own)
        print(f'{path}: umf generate "{prompt}" {flags} --people {people} --seconds '
              f"{seconds:g} --seed {args.seed} --format gif")  # fmt: skip
    for name, shown, person, seed in REROLLS:
        scene = pipe.reroll(scenes[shown], person, seed=seed)
        t = scene.num_frames
        frames = [round(i * (t - 1) / (FRAMES - 1)) for i in range(FRAMES)]
        caption = f"{scene.text} (person {person} re-rolled, seed {seed})"
        path = save_still(scene.joints, args.out / f"{name}.png", frames, caption=caption)
        print(f"{path}: umf reroll <{shown}.npz> --person {person} --seed {seed} --format gif")
    for name, shown, frames in CLOSE:
        person = scenes[shown].joints[0]
        fx, fz = start_facing(person)  # the camera stands where the person looks
        step = (frames[1] - frames[0]) / scenes[shown].fps
        caption = f"{scenes[shown].text} (seen from the front, every {step:g} s)"
        azim = math.degrees(math.atan2(fx, fz))
        path = save_still(person, args.out / f"{name}.png", frames, caption=caption,
                          azim=azim, elev=10.0, size=(300, 400))  # fmt: skip
        print(f"{path}: frames {frames[0]}-{frames[-1]} of {shown}.png's person")


if __name__ == "__main__":
    main()
