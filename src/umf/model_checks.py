"""Checks of a model before it is built or loaded: every config value (types, ranges,
choices) and every weight file (shapes from the headers, then finite values), each
failure one line naming the field or tensor."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from umf.errors import UMFError
from umf.validation import MAX_FLOW_STEPS, check_float, check_int

# --------------------------------------------------------------------- model configs
MAX_CONFIG_INT = 1 << 16  # any size or count in a model config (d_model, frames, steps ...)


MAX_LAYERS = 256


MAX_MODEL_BYTES = 8 << 30  # parameters and buffers of VAE + P-Flow + S-Flow


CHOICES = {
    "layout": ("1d", "2d"),
    "solver": ("euler", "heun", "rk4"),
    "encoder": ("minilm", "clip"),
    "text_encoder": ("minilm", "clip", "clip-tokens"),
    "family": ("paper", "small"),
    "warm_proposal": ("pflow", "retrieved"),
    "person_composition": ("joint", "and"),
}


_UNBOUNDED = {"max_steps", "warmup_steps", "val_every", "ckpt_every", "log_every", "seed"}


_NON_NEGATIVE = {"reaction_noise", "context_noise", "w_root_vel", "position_fusion",
                 "guidance", "fine_guidance", "person_guidance", "foot_loss", "place_loss",
                 "joint_loss", "warm_glide", "warm_pace", "warm_timing",
                 "warm_clear"}  # fmt: skip  # >= 0


_POSITIVE = {"root_fusion", "height_fusion", "reaction_root_fusion"}  # floats > 0


# floats in [0, 1]
_FRACTIONS = {"balance_labels", "caption_mix", "p_person_drop", "p_scene_drop",
              "foot_loss_min_t", "place_loss_max_t", "warm_start", "own_warm",
              "warm_together", "warm_take", "warm_margin", "warm_start_group"}  # fmt: skip


def _check_value(where: str, kind: str, value: Any) -> None:
    """One config field against its annotation: types, non-negative, finite, bounded."""
    optional = "None" in kind
    if value is None:
        if not optional:
            raise UMFError(f"{where} must not be null")
        return
    name = where.rsplit(".", 1)[-1]
    if kind.startswith("tuple[str"):  # word lists: may be empty
        if not isinstance(value, tuple | list):
            raise UMFError(f"{where} must be a list, got {value!r}")
        for v in value:
            if not isinstance(v, str):
                raise UMFError(f"{where} must be a list of words, got {v!r} in it")
        if name == "respell":
            from umf.text import respell_table

            respell_table(value)
        if name == "caption_mix_from":
            from umf.config import metadata_pairs

            metadata_pairs(value, where)
        if name in ("label_repeats", "relation_repeats"):  # labels are the corpus's to say
            from umf.config import key_times
            from umf.data.scene_relations import RELATIONS

            keys = set(key_times(value, where))
            unknown = sorted(keys - set(RELATIONS)) if name == "relation_repeats" else []
            if unknown:
                raise UMFError(f"{where}: no relation {unknown[0]!r}; relations: "
                               f"{', '.join(RELATIONS)}")  # fmt: skip
        return
    if kind.startswith("tuple"):
        if not isinstance(value, tuple | list) or not value:
            raise UMFError(f"{where} must be a non-empty list, got {value!r}")
        inner = "float" if "float" in kind else "int"
        for v in value:
            _check_value(where, inner, v)
        return
    if kind.startswith("bool"):
        if not isinstance(value, bool):
            raise UMFError(f"{where} must be true or false, got {value!r}")
    elif kind.startswith("int") and name in ("steps", "pair_steps"):
        check_int(where, value, 1, MAX_FLOW_STEPS)
    elif kind.startswith("int"):
        hi = 2**63 - 1 if name in _UNBOUNDED else MAX_LAYERS if "layers" in name else MAX_CONFIG_INT
        check_int(where, value, 0, hi)
    elif kind.startswith("float"):
        lo = 0.0 if name in _NON_NEGATIVE | _FRACTIONS | _POSITIVE else -1e9
        check_float(where, value, lo, 1.0 if name in _FRACTIONS else 1e9)
        if name in _POSITIVE and value <= 0:  # a weight of 0 leaves the path undetermined
            raise UMFError(f"{where} must be greater than 0, got {value}")
    elif kind.startswith("str"):
        if not isinstance(value, str):
            raise UMFError(f"{where} must be a string, got {value!r}")
        if name in CHOICES and value not in CHOICES[name]:
            raise UMFError(f"{where} must be one of {', '.join(CHOICES[name])}, got {value!r}")


def check_config_values(config: Any, prefix: str = "") -> None:
    """Every field of a (nested) config dataclass: right type, finite, in range."""
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        where = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            check_config_values(value, where + ".")
        else:
            _check_value(where, str(f.type), value)
    if not prefix:
        check_float("fps", config.fps, 1.0, 1000.0)
        if config.vae.max_frames < 15:
            raise UMFError(f"vae.max_frames must be at least 15, got {config.vae.max_frames}")
        for flow in ("pflow", "sflow"):
            d = getattr(config, flow).denoiser
            if d.person_head and not d.person_text:
                raise UMFError(f"{flow}.denoiser.person_head needs {flow}.denoiser.person_text")
        if config.sflow.context_condition and config.sflow.shared_backbone:
            raise UMFError("sflow.context_condition needs the S-Flow's own transformer "
                           "(not sflow.shared_backbone)")  # fmt: skip
        if config.sflow.warm_neighbours < 1:
            raise UMFError(f"sflow.warm_neighbours must be at least 1, got "
                           f"{config.sflow.warm_neighbours}")  # fmt: skip
        sflow = config.sflow
        if sflow.warm_side and not (sflow.warm_proposal == "retrieved" and sflow.warm_shortlist):
            raise UMFError("sflow.warm_side needs sflow.warm_proposal 'retrieved' and "
                           "sflow.warm_shortlist > 0 (it narrows that shortlist)")  # fmt: skip
        if sflow.warm_margin and not (sflow.warm_proposal == "retrieved" and sflow.warm_shortlist):
            raise UMFError("sflow.warm_margin needs sflow.warm_proposal 'retrieved' and "
                           "sflow.warm_shortlist > 0 (it narrows that shortlist)")  # fmt: skip
        if sflow.warm_together and not (sflow.warm_proposal == "retrieved" and sflow.warm_pace):
            raise UMFError("sflow.warm_together needs sflow.warm_proposal 'retrieved' and "
                           "sflow.warm_pace > 0 (it says whose pace that is)")  # fmt: skip
        if sflow.warm_play and not sflow.warm_together:
            raise UMFError("sflow.warm_play needs sflow.warm_together > 0 (it plays the "
                           "reactions that travel with person 1 at person 1's pace)")  # fmt: skip
        if sflow.warm_follow is not None and not sflow.warm_play:
            raise UMFError("sflow.warm_follow needs sflow.warm_play (it carries the played "
                           "reactions along person 1's path)")  # fmt: skip
        if sflow.warm_apart and sflow.warm_proposal != "retrieved":
            raise UMFError("sflow.warm_apart needs sflow.warm_proposal 'retrieved' (it "
                           "narrows the reactions retrieved)")  # fmt: skip
        if sflow.warm_clear and not sflow.warm_apart:
            raise UMFError("sflow.warm_clear needs sflow.warm_apart (it keeps the same people "
                           "apart, over their whole bodies)")  # fmt: skip
        if sflow.warm_extend and not (sflow.warm_apart and sflow.warm_together):
            raise UMFError("sflow.warm_extend needs sflow.warm_apart and sflow.warm_together "
                           "> 0 (it places people who travel with person 1)")  # fmt: skip
        if sflow.warm_start_group and not sflow.warm_start:
            raise UMFError("sflow.warm_start_group needs sflow.warm_start > 0 (it is the "
                           "same second pass's time beside 2+ people)")  # fmt: skip
        for name in ("warm_start", "own_warm", "warm_take", "warm_start_group"):
            if getattr(sflow, name) >= 1.0:
                raise UMFError(f"sflow.{name} must be below 1, got {getattr(sflow, name)}")
        for stage in ("train_vae", "train_pflow"):  # the losses on decoded people: S-Flow's
            for name in ("foot_loss", "place_loss", "joint_loss"):
                if getattr(getattr(config, stage), name):
                    what = name.replace("_", " ")
                    raise UMFError(f"{stage}.{name}: only train_sflow has a {what}")


def check_weight_shapes(path: Path, modules: dict[str, Any]) -> None:
    """Each module file's tensor shapes against the (meta) modules, reading headers only."""
    from safetensors import safe_open

    for name, module in modules.items():
        f = path / f"{name}.safetensors"
        if not f.exists():
            raise UMFError(f"{path}: missing module file {f.name}")
        try:
            with safe_open(str(f), framework="pt") as fh:
                shapes = {k: tuple(fh.get_slice(k).get_shape()) for k in fh.keys()}
        except Exception as exc:  # safetensors raises several types for a damaged header
            raise UMFError(f"{f}: corrupt module file ({type(exc).__name__})") from exc
        for key, t in module.state_dict().items():
            if key in shapes and shapes[key] != tuple(t.shape):
                raise UMFError(
                    f"{path}: tensor {name}.{key} has shape {shapes[key]} in the checkpoint "
                    f"but {tuple(t.shape)} in config.json"
                )


def check_model_weights(modules: dict[str, Any], normalizer: Any, path: Path) -> None:
    """Loaded weights and normaliser must be finite, the normaliser's std positive."""
    import torch

    for name, module in modules.items():
        for key, t in module.state_dict().items():
            if t.is_floating_point() and not bool(torch.isfinite(t).all()):
                raise UMFError(f"{path}: weights {name}.{key} contain NaN or infinite values")
    mean, std = normalizer.mean, normalizer.std
    if not bool(torch.isfinite(mean).all() & torch.isfinite(std).all()):
        raise UMFError(f"{path}: the normaliser contains NaN or infinite values")
    if not bool((std > 0).all()):
        raise UMFError(f"{path}: the normaliser has a zero or negative std")
