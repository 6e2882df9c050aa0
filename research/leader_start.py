"""Where a generated person 1 starts: decoded positions against decoded velocities.

    python research/leader_start.py [MODEL_DIR] [--seeds 6] [--prompt "..."]

For each seed (4 s, 2 people, no clean-up): person 1's decoded pelvis (the position slots)
at the first and last frame, the distance its decoded velocities add up to, and where the
fused floor path starts (``vae.root_fusion``, as the pipeline fuses person 1), without and
with ``vae.pin_leader_start``; then person 2's start along person 1's heading, in the scene
as delivered by each. Every training crop starts person 1 over the origin, and people 2..N
are placed relative to it.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from umf.pipeline import UMFPipeline, default_model_dir
from umf.representation import POS, VEL, fuse_positions, pin_floor_start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--prompt", default="Two people run side by side.")
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    pipe = UMFPipeline.from_pretrained(args.model or default_model_dir())
    seen = []
    decode_raw = pipe._decode_raw

    def spy(z, frames):  # the last call decodes the scene's people together
        seen.append(out := decode_raw(z, frames))
        return out

    pipe._decode_raw = spy
    vae = pipe.config.vae
    print(f"{args.prompt!r}, person 1 (m, along +z = its first-frame facing):")
    for seed in range(args.seeds):
        ahead = {}
        for pin in (False, True):
            vae.pin_leader_start = pin
            seen.clear()
            (s,) = pipe(args.prompt, num_people=2, seconds=4.0, seed=seed, fit=False,
                        separate=False)  # fmt: skip
            j = np.asarray(s.joints)[:, 0, 0, [0, 2]]
            ahead[pin] = float(j[1, 1] - j[0, 1])
        raw = seen[-1][:1]  # person 1
        pos = raw[0, :, POS].reshape(-1, 22, 3)[:, 0]
        vel = raw[0, :-1, VEL].reshape(-1, 22, 3)[:, 0]
        fused = fuse_positions(raw, *vae.fusion_weights())
        start = fused[0, 0, POS][[0, 2]]
        pinned = pin_floor_start(fused)[0, 0, POS][[0, 2]]
        print(
            f"seed {seed}: positions z {pos[0, 2]:+.2f} -> {pos[-1, 2]:+.2f} "
            f"(travel {float((pos[-1] - pos[0])[[0, 2]].norm()):.1f}), velocities add up to "
            f"{float(vel.sum(0)[[0, 2]].norm()):.1f}; fused start ({start[0]:+.2f}, "
            f"{start[1]:+.2f}), pinned ({pinned[0]:+.2f}, {pinned[1]:+.2f}); person 2 starts "
            f"{ahead[False]:+.2f} ahead, pinned {ahead[True]:+.2f}"
        )


if __name__ == "__main__":
    main()
