"""Finding and loading the model a command names (the bundled one by default), with
one-line errors; shared by generate, react, serve and view."""

from __future__ import annotations

from pathlib import Path

from umf.errors import UMFError


def load_pipeline(model: Path | None):
    """The bundled model, or the model directory the user named (one-line errors)."""
    from umf.pipeline import UMFPipeline, default_model_dir

    if model is None and not default_model_dir().exists():
        raise UMFError("no bundled model in this install; pass --model DIR (see umf train)")
    return UMFPipeline.from_pretrained(model)


def peek_config(model: Path | None):
    """The model's config.json for model-specific checks before loading, or None when it
    cannot be read (loading then reports why)."""
    import json

    from umf.config import UMFConfig
    from umf.model_checks import check_config_values
    from umf.pipeline import default_model_dir

    path = (model if model is not None else default_model_dir()) / "config.json"
    try:
        config = UMFConfig.from_dict(json.loads(path.read_text()))
        check_config_values(config)
    except (OSError, ValueError, UMFError):
        return None
    return config
