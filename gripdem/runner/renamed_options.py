"""Options renamed so that each name has one meaning, and their old names kept working for one
release (``docs/reference/configuration.md#renamed-options``): a run that uses an old name runs
as with the new one and prints one line naming it. :func:`apply_deprecated_names` is called by
:func:`~gripdem.runner.config_schema.check_combination`, first, on every job's config."""

from __future__ import annotations

import logging
from typing import Any

from omegaconf import DictConfig, open_dict

from gripdem.data.protocols import RENAMED_PROTOCOLS
from gripdem.runner.run_names import hydra_choices

log = logging.getLogger("gripdem.runner.config_schema")


def _value(option: Any) -> Any:
    """An option's value (an enum of the schema or a plain value)."""
    return getattr(option, "value", option)


#: renamed options: old name -> (new name, the release that removes the old one)
RENAMED = {
    "experiment=fast": ("experiment=default", "0.2.0"),
    "model.fast_steps": ("model.train_steps", "0.2.0"),
    "model=interaction": ("model=contact", "0.2.0"),
    "model/encoder=interaction": ("model/encoder=contact", "0.2.0"),
    "model.encoder.name=interaction": ("model.encoder.name=contact", "0.2.0"),
    "data.protocol=paper": ("data.protocol=in_sample", "0.2.0"),
    "data.paper_windows": ("data.in_sample_windows", "0.2.0"),
}
#: the old names whose line this process has printed
PRINTED: set[str] = set()
#: renamed config files: (group, old file) -> the ``RENAMED`` key
_RENAMED_CHOICES = {
    ("experiment", "fast"): "experiment=fast",
    ("model", "interaction"): "model=interaction",
    ("model/encoder", "interaction"): "model/encoder=interaction",
}


def apply_deprecated_names(cfg: DictConfig) -> list[str]:
    """Old option names still work for one release: each used one prints one line naming its
    replacement (``RENAMED``), and an old option's or value's setting is carried over to the
    new one. Returns the old names found."""
    found = [
        old
        for (group, file), old in _RENAMED_CHOICES.items()
        if hydra_choices(cfg).get(group) == file
    ]
    with open_dict(cfg):
        if cfg.model.get("fast_steps") is not None:
            found.append("model.fast_steps")
            cfg.model.train_steps = int(cfg.model.fast_steps)
            cfg.model.fast_steps = None
        if _value(cfg.model.encoder.get("name")) == "interaction":
            found.append("model.encoder.name=interaction")
            cfg.model.encoder.name = "contact"
        protocol = _value(cfg.data.get("protocol"))
        if protocol in RENAMED_PROTOCOLS:
            found.append(f"data.protocol={protocol}")
            cfg.data.protocol = RENAMED_PROTOCOLS[protocol]
        if cfg.data.get("paper_windows") is not None:
            found.append("data.paper_windows")
            cfg.data.in_sample_windows = int(cfg.data.paper_windows)
            cfg.data.paper_windows = None
    for old in found:
        if old in PRINTED:  # a sweep checks each job before it starts and again inside it
            continue
        PRINTED.add(old)
        new, removed = RENAMED[old]
        log.warning("%s is deprecated: use %s (the old name goes in gripdem %s)", old, new, removed)
    return found
