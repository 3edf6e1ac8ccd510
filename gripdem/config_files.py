"""Where gripdem's configuration files are: ``conf/`` of the source tree, reached from the
package as ``gripdem/conf`` (a link to ``../conf`` in the repository; real files in a wheel,
``pyproject.toml``'s package data), so that an editable install and a wheel find them alike."""

from __future__ import annotations

from pathlib import Path

#: the Hydra config folder (``config.yaml``, ``simulate.yaml`` and the config groups)
CONFIG_DIR = Path(__file__).resolve().parent / "conf"


def config_dir() -> Path:
    """:data:`CONFIG_DIR`, checked: an install without its configs is named, not guessed at."""
    if not (CONFIG_DIR / "config.yaml").is_file():
        raise FileNotFoundError(
            f"{CONFIG_DIR / 'config.yaml'}: gripdem's configuration files are missing from this "
            "install (a wheel must hold gripdem/conf/; reinstall gripdem)"
        )
    return CONFIG_DIR
