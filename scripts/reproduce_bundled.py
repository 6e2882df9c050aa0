"""Train the bundled model again, from the corpus, in one command: every stage of its lineage.

The bundled model was made in steps across several sessions (a VAE and both flows on one
GPU, then fine-tunes on a CPU; each step has a results page). This runs the same steps
in order, with the options those pages and the shipped ``config.json`` record, into
``--work`` (default ``~/umf-runs/bundled``), and writes the model to ``WORK/model``
(the last eleven training stages, ``teach``, ``reteach``, ``rebalance``, ``settle``,
``pace``, ``person``, ``person2``, ``place``, ``gait``, ``leader`` and ``jump``, and the bank
of real reactions the last stage, ``name``, writes (``umf train reactions``, 3-5 min),
need the full corpus of ``make corpus`` with ``../shared``: Bandai and the CMU and DeepMimic
mocap):

    python scripts/reproduce_bundled.py [--work DIR] [--corpus out/corpus] [--dry-run]
        [--max-steps N]   # every training stage cut to N steps, one latent pass: a quick
                          # check of the wiring (the whole chain: 7 min here alone)

Each stage leaves ``WORK/done/<stage>`` when it ends; a killed run started again skips
the finished stages and resumes the training it was in (``umf train --resume``). The
first stage (VAE, P-Flow, S-Flow from scratch: 2,000 x 128 and 5,600 x 512 twice) wants a
GPU (about 10 min on an H200; many hours on this 2-core CPU, not measured). The CPU fine-tunes
after it take about 4.3 h here (2 h of them the S-Flow; ``settle`` 20 min, ``pace``
18 min, for the per-person prompts ``person`` 41 min and ``person2`` 23 min, ``place``
12 min, ``gait`` 12 min, ``leader`` 20 min and ``jump`` 11 min). ``pace``
was trained on a corpus of the composer of its day (partners of side-by-side scenes at the
leader's pace and in step; but for its fallback, changed since, 24 of 3,000 training
scenes), ``person`` and ``person2`` on the current one (with ``stand_facing`` and the own
captions); the stages before on the composer of their day, whose side-by-side partners were
paired at random: a corpus prepared now gives every stage the new scenes.
``--dry-run`` prints the commands and runs nothing.

Not bit-for-bit: the GPU stages ran with TF32 and the code changed between the steps, so
expect the scores of ``results/umf-small-bandai-20261127c`` within their intervals, not the
same weights. What the pages leave out and this fills in: the S-Flow's reaction-noise
fine-tunes after the first validated every 400 steps (the logs and the shipped config say so), and
the sampling options set by hand on the way (guidance 2, ``sflow.pair_steps`` 4, the root
fusion of ``umf-small-bandai-20261127``) are applied once, after the GPU stage: they do not
change what is trained.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

NAME = "umf-small-bandai-20261219"
PLACE_WEIGHT = 0.1


def sets(prefix: str, **options: object) -> list[str]:
    """``--set prefix.key=value`` for each option (lists as ``[a,b]``, booleans lower case)."""
    out = []
    for key, value in options.items():
        if isinstance(value, bool):
            value = str(value).lower()
        elif isinstance(value, list | tuple):
            value = "[" + ",".join(map(str, value)) + "]"
        out += ["--set", f"{prefix}.{key}={value}"]
    return out


# results/umf-small-bandai-h200-20261126 (the VAE) and -h200-20261126b (both flows)
GPU_VAE = dict(max_steps=2000, batch_size=128, warmup_steps=300, val_every=1000, ckpt_every=1000,
               log_every=25)  # fmt: skip
GPU_FLOW = dict(max_steps=5600, batch_size=512, lr=0.0004, warmup_steps=300, ema_decay=0.999,
                val_every=400, ckpt_every=400)  # fmt: skip
GPU_PASSES = {"pflow": 6, "sflow": 8}
# set by hand on the way (h200-20261126b, 20261126c, 20261127): sampling and decoding only
SAMPLING = [
    "pflow.guidance=2.0",
    "sflow.guidance=2.0",
    "sflow.pair_steps=4",
    "vae.root_fusion=0.0002",
    "vae.height_fusion=1",
    "vae.reaction_root_fusion=0.001",
]
# results/umf-small-bandai-20261126c: the S-Flow's noisy reaction start, annealed
REACTION_NOISE = [("rn0.5", 0.5, 800, 200), ("rn0.5b", 0.5, 1600, 400),
                  ("rn0.25c", 0.25, 1600, 400), ("rn0.125d", 0.125, 1600, 400)]  # fmt: skip
SFLOW_FT = dict(lr=0.0001, warmup_steps=20, batch_size=128, latent_passes=2, ema_decay=0.99,
                ckpt_every=200, num_workers=0)  # fmt: skip
# results/umf-small-bandai-20261127b: short clips extended, P-Flow then the decoder
EXTEND = dict(hold_rest=True, repeat_gait=True)
PFLOW_EXTEND = dict(**EXTEND, respell_captions=True, lr=0.0001, warmup_steps=20,
                    max_steps=1000, batch_size=128, ema_decay=0.99, latent_passes=4,
                    ckpt_every=250, val_every=500, num_workers=0)  # fmt: skip
DECODER = dict(decoder_only=True, **EXTEND, min_frames=140, max_frames=160, lr=0.0002,
               warmup_steps=50, max_steps=600, batch_size=64, val_every=200, ckpt_every=100,
               num_workers=0)  # fmt: skip
# results/umf-small-bandai-20261127c: unmarked wordings for every style
PFLOW_MIX = dict(**EXTEND, respell_captions=True, caption_mix=0.5, caption_mix_within=["content"],
                 caption_mix_from=["style=normal"], lr=0.0002, warmup_steps=20, max_steps=1500,
                 batch_size=128, ema_decay=0.99, latent_passes=4, ckpt_every=250,
                 val_every=500, num_workers=0)  # fmt: skip


# results/umf-small-bandai-20261202: taught the real mocap (CMU salsa and handshake takes,
# DeepMimic) with `umf train finetune` (its FINETUNE defaults, then these); needs the full
# corpus (`make corpus` with ../shared, which adds the mocap libraries)
TEACH = [*sets("train_vae", max_steps=600, real_repeats=60),
         *sets("train_pflow", max_steps=2000, real_repeats=60),
         *sets("train_sflow", max_steps=2000, real_repeats=60)]  # fmt: skip

# results/umf-small-bandai-20261202b: taught again, every label weighted alike and the VAE
# longer at twice the rate, so that it reconstructs flips and crawls (the release ran the VAE
# on a 1,600-step schedule and kept its step-1000 checkpoint; this schedules 1,000)
RETEACH = [*sets("train_vae", max_steps=1000, balance_labels=1.0, lr=0.0002, real_repeats=60,
                 val_every=200),
           *sets("train_pflow", max_steps=1600, real_repeats=60, balance_labels=1.0),
           *sets("train_sflow", max_steps=1600, real_repeats=60)]  # fmt: skip


# results/umf-small-bandai-20261202c: the P-Flow alone fine-tuned again with labels half
# balanced (0.5), on the reteach VAE: the single-person FID back within its old interval
REBALANCE = sets("train_pflow", max_steps=1600, real_repeats=60, balance_labels=0.5)

# results/umf-small-bandai-20261203: the P-Flow once more, the same way, with slow clip ends
# (the getups) eased to a stop and held (train_pflow.settle)
SETTLE = sets("train_pflow", max_steps=1600, real_repeats=60, balance_labels=0.5, settle=True)

# results/umf-small-bandai-20261204: the S-Flow alone, on a corpus whose side-by-side
# partners walk at the leader's pace and in step (the composer of that release)
PACE = sets("train_sflow", max_steps=2000, real_repeats=60, val_every=400, ckpt_every=100)


# results/umf-small-bandai-20261204b: both flows take per-person prompts (a projection grown
# at zero), fine-tuned on a corpus with the stand_facing relation and own captions; round 2
# serves the stand_facing scenes 8 times per epoch
PERSON = ["--set", "pflow.denoiser.person_text=true", "--set", "sflow.denoiser.person_text=true",
          *sets("train_pflow", max_steps=1200, lr=0.0002, real_repeats=60, val_every=300,
                ckpt_every=50),
          *sets("train_sflow", max_steps=1500, lr=0.0002, real_repeats=60, val_every=300,
                ckpt_every=100)]  # fmt: skip
PERSON2 = [*sets("train_pflow", max_steps=800, lr=0.0002, real_repeats=60,
                 relation_repeats=["stand_facing=8"], val_every=400, ckpt_every=50),
           *sets("train_sflow", max_steps=1500, lr=0.0003, real_repeats=60,
                 relation_repeats=["stand_facing=8"], val_every=500, ckpt_every=100)]  # fmt: skip

# results/umf-small-bandai-20261208: the S-Flow alone, with a loss on where its decoded
# reaction stands (train_sflow.place_loss) and the relations it failed most served 4 times
PLACE = sets("train_sflow", max_steps=1500, lr=0.0002, warmup_steps=20, real_repeats=60,
             relation_repeats=["walk_side_by_side=4", "run_side_by_side=4", "bow_back=4",
                               "spar=4"],
             val_every=500, ckpt_every=100, place_loss=PLACE_WEIGHT)  # fmt: skip

# results/umf-small-bandai-20261209: the same recipe again, the short striding scenes carried
# on by their gait (train_sflow.repeat_scene_gait; the bank of reactions follows it)
GAIT = [*PLACE, *sets("train_sflow", repeat_scene_gait=True)]

# results/umf-small-bandai-20261216: the P-Flow alone, as person2 left it, with each short
# scene's person 1 carried on by their own gait (train_pflow.repeat_leader_gait): a 4 s run
# side by side led straight
LEADER = sets("train_pflow", max_steps=1200, lr=0.0002, real_repeats=60,
              relation_repeats=["stand_facing=8"], val_every=400, ckpt_every=100,
              repeat_leader_gait=True)  # fmt: skip

# results/umf-small-bandai-20261219: the same again from the leader stage's model, the jump
# served 4 times as often (wise-pflow-20261206: a 4 s jump lifts the pelvis 15 cm in 8 of 8
# seeds, 6 before)
JUMP = [*LEADER, *sets("train_pflow", label_repeats=["jump=4"])]


# the last stage's sampling options (results/umf-small-bandai-20261204b, 20261206, 20261207)
NAMED = ["pflow.person_guidance=3.0", "sflow.person_guidance=3.0", "sflow.warm_start=0.5",
         "sflow.warm_proposal=retrieved", "sflow.warm_glide=0.3", "sflow.warm_pace=0.15",
         "sflow.warm_shortlist=64", "pflow.person_composition=and",
         "sflow.own_warm=0.5", "sflow.warm_side=true", "sflow.warm_timing=8",
         "sflow.warm_together=0.8", "vae.pin_leader_start=true", "sflow.warm_play=true",
         "sflow.warm_apart=true", "sflow.warm_take=0.7", "sflow.warm_margin=0.15",
         "sflow.warm_start_group=0.7", "sflow.warm_clear=0.55",
         "sflow.warm_extend=true", "sflow.warm_follow=20"]  # fmt: skip


class Stage(NamedTuple):
    name: str
    commands: list[list[str]]
    env: dict[str, str]
    writes: Path | None = None  # a model written whole: one left by a kill is removed first


def stages(work: Path, corpus: Path, max_steps: int | None = None) -> list[Stage]:
    """Every stage, in order; ``max_steps`` cuts
    every training stage short and its flows' latent banks to one pass (the stage's last
    options, so they win)."""
    py = sys.executable
    scripts = Path(__file__).resolve().parent

    def cut(*trained: str) -> list[str]:
        if max_steps is None:
            return []
        opts = [f"train_{t}.max_steps={max_steps}" for t in trained]
        opts += [f"train_{t}.latent_passes=1" for t in trained if t != "vae"]
        return [a for o in opts for a in ("--set", o)]

    umf = [py, "-m", "umf"]  # the umf command of this environment
    c = ["--corpus", str(corpus)]

    def finetune(stage: str, run: str, init: Path, options: list[str]) -> list[list[str]]:
        out = work / "runs" / run
        resume = ["--resume"] if out.exists() else []
        return [[*umf, "train", stage, *c, "--out", str(out), "--init", str(init),
                 *options, *cut(stage), *resume]]  # fmt: skip

    def export(run: str, base: Path, model: Path) -> list[str]:
        return [*umf, "train", "export", "--run", str(work / "runs" / run), "--out", str(model),
                "--base", str(base)]  # fmt: skip

    m = {k: work / "models" / k for k in ("gpu", "sampling", "hg", "dec", "mix")}
    gpu_sets = sets("train_vae", **GPU_VAE)
    for f in ("pflow", "sflow"):
        gpu_sets += sets(f"train_{f}", **GPU_FLOW, latent_passes=GPU_PASSES[f])
    gpu_sets += cut("vae", "pflow", "sflow")
    workers = str(max(0, min(8, (os.cpu_count() or 1) - 1)))  # loader processes per stage
    gpu_env = {"OUT": str(m["gpu"]), "RUNS": str(work / "runs" / "gpu"), "CORPUS": str(corpus)}
    for w in ("VAE_WORKERS", "PFLOW_WORKERS", "SFLOW_WORKERS"):
        gpu_env[w] = os.environ.get(w, workers)

    def variant(name: str, src: Path, dst: Path, *options: str) -> Stage:
        command = [py, str(scripts / "model_variant.py"), str(src), str(dst), *options]
        return Stage(name, [command], {}, writes=dst)  # model_variant refuses an existing dst

    out = [Stage("gpu", [[py, str(scripts / "gpu_flows_train.py"), "864000", "--vae",
                          *gpu_sets]], gpu_env),
           variant("sampling", m["gpu"], m["sampling"],
                   *[a for o in SAMPLING for a in ("--set", o)])]  # fmt: skip
    prev = m["sampling"]
    for run, sigma, steps, val in REACTION_NOISE:
        model = work / "models" / run
        opts = sets("sflow", reaction_noise=sigma)
        opts += sets("train_sflow", **SFLOW_FT, max_steps=steps, val_every=val)
        out.append(Stage(run, [*finetune("sflow", run, prev, opts), export(run, prev, model)], {}))
        prev = model
    m["sflow"] = prev  # the S-Flow's last fine-tune
    hg = finetune("pflow", "hg", m["sflow"], sets("train_pflow", **PFLOW_EXTEND))
    out.append(Stage("hg", [*hg, export("hg", m["sflow"], m["hg"])], {}))
    dec = finetune("vae", "dec", m["sflow"], sets("train_vae", **DECODER))
    out.append(Stage("dec", [*dec, export("dec", m["hg"], m["dec"])], {}))
    mix = finetune("pflow", "mix", m["dec"], sets("train_pflow", **PFLOW_MIX))
    out.append(Stage("mix", [*mix, export("mix", m["dec"], m["mix"])], {}))
    teach = work / "runs" / "teach"
    out.append(Stage("teach", [[*umf, "train", "finetune", "--from", str(m["mix"]), *c, "--out",
                                str(teach), *TEACH, *cut("vae", "pflow", "sflow"),
                                *(["--resume"] if teach.exists() else [])]], {}))  # fmt: skip
    reteach = work / "runs" / "reteach"
    out.append(Stage("reteach", [[*umf, "train", "finetune", "--from", str(teach / "model"), *c,
                                  "--out", str(reteach), *RETEACH, *cut("vae", "pflow", "sflow"),
                                  *(["--resume"] if reteach.exists() else [])]], {}))  # fmt: skip

    def one_flow(name: str, start: Path, flow: str, options: list[str]) -> Stage:
        run = work / "runs" / name
        resume = ["--resume"] if run.exists() else []
        return Stage(name, [[*umf, "train", "finetune", "--from", str(start), *c, "--out",
                             str(run), "--stages", flow, *options, *cut(*flow.split(",")),
                             *resume]], {})  # fmt: skip

    rebalance = work / "runs" / "rebalance"
    out.append(one_flow("rebalance", reteach / "model", "pflow", REBALANCE))
    settle = work / "runs" / "settle"
    out.append(one_flow("settle", rebalance / "model", "pflow", SETTLE))
    pace = work / "runs" / "pace"
    out.append(one_flow("pace", settle / "model", "sflow", PACE))
    # results/step-budget-val-20261203: 5 + 5 P-Flow steps score like 45 + 5, 2.4x faster
    m["steps"] = work / "models" / "steps"
    out.append(variant("steps", pace / "model", m["steps"], "--set", "pflow.steps=[5,5]"))
    out.append(one_flow("person", m["steps"], "pflow,sflow", PERSON))
    person = work / "runs" / "person"
    out.append(one_flow("person2", person / "model", "pflow,sflow", PERSON2))
    # results/umf-small-bandai-20261208: the S-Flow taught where its reactions stand
    out.append(one_flow("place", work / "runs" / "person2" / "model", "sflow", PLACE))
    out.append(one_flow("gait", work / "runs" / "place" / "model", "sflow", GAIT))
    out.append(one_flow("leader", work / "runs" / "gait" / "model", "pflow", LEADER))
    out.append(one_flow("jump", work / "runs" / "leader" / "model", "pflow", JUMP))
    # results/umf-small-bandai-20261204b: own prompts guided at 3 apart from the scene's 2;
    # results/umf-small-bandai-20261206: gliding people 2..N warm-started from a real
    # reaction travelling as they do, from the bank of the corpus's train scenes;
    # results/umf-small-bandai-20261207: own prompts conjoined in the P-Flow, own-prompted
    # people 2..N warm-started from the P-Flow's motion for their prompt;
    # results/umf-small-bandai-20261210: an answer retrieved from the bank waits as long
    # after person 1 as it did in its scene; results/umf-small-bandai-20261211: person 1's
    # fused path starts over the origin, and people travelling with them keep their pace;
    # results/umf-small-bandai-20261212: their partner is played at their pace, and person
    # k >= 3 keeps off the spots of people 2..k - 1; results/umf-small-bandai-20261213: a
    # couple worded like a touching take is finished from one of its crops (the bank keeps
    # the touching takes whole); results/umf-small-bandai-20261214: a prompt worded like no
    # caption (a group's) retrieves among the reactions of its nearest captions only, and
    # person k >= 3 is sampled again from 0.7 on the path towards their proposal;
    # results/umf-small-bandai-20261215: and kept 0.55 m off everybody's whole body;
    # results/umf-small-bandai-20261217: a single file's walker starts behind the one before;
    # results/umf-small-bandai-20261218: a partner carried along a leader who turns over 20
    # degrees, sampled again as if straight where that pass touches someone;
    # results/umf-small-bandai-20261219: the jump stage's P-Flow, nothing else new
    name = variant("name", work / "runs" / "jump" / "model", work / "model",
                   *[a for o in NAMED for a in ("--set", o)], "--name", NAME)  # fmt: skip
    reactions = [*umf, "train", "reactions", "--model", str(work / "model"), *c]
    out.append(name._replace(commands=[*name.commands, reactions]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path.home() / "umf-runs" / "bundled")
    ap.add_argument("--corpus", type=Path, default=Path("out/corpus"))
    ap.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    ap.add_argument("--max-steps", type=int, default=None,
                    help="cut every training stage to N steps and one latent pass "
                    "(a check of the wiring)")  # fmt: skip
    args = ap.parse_args()
    if args.max_steps is not None and args.max_steps < 1:
        sys.exit("error: --max-steps must be at least 1")
    if not args.dry_run and not (args.corpus / "manifest.json").exists():
        sys.exit(f"error: no corpus at {args.corpus} (make corpus, or umf data prepare)")
    done = args.work / "done"
    plan = args.work / "plan.json"  # a cut check and a full run must not share stages
    want = json.dumps({"max_steps": args.max_steps})
    if not args.dry_run:
        if plan.exists() and plan.read_text() != want:
            sys.exit(f"error: {args.work} holds a run with {plan.read_text()}, not {want}; "
                     "use another --work")  # fmt: skip
        args.work.mkdir(parents=True, exist_ok=True)
        plan.write_text(want)
    for name, commands, env, writes in stages(args.work, args.corpus, args.max_steps):
        if (done / name).exists():
            print(f"== {name}: done before", flush=True)
            continue
        print(f"== {name}", flush=True)
        if writes is not None and writes.exists() and not args.dry_run:
            shutil.rmtree(writes)
        for cmd in commands:
            print("   " + " ".join(f"{k}={v}" for k, v in env.items()) + " " * bool(env)
                  + shlex.join(cmd), flush=True)  # fmt: skip
            if not args.dry_run:
                try:
                    rc = subprocess.run(cmd, env={**os.environ, **env}).returncode
                except OSError as e:
                    sys.exit(f"error: stage {name}: cannot run {cmd[0]}: {e}")
                if rc:
                    sys.exit(f"error: stage {name} failed (exit {rc}); run again to resume")
        if not args.dry_run:
            done.mkdir(parents=True, exist_ok=True)
            (done / name).touch()
    if not args.dry_run:
        print(f"model written to {args.work / 'model'}")


if __name__ == "__main__":
    main()
