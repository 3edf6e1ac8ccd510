"""Options renamed in gripdem 0.1.0 so that each name has one meaning; their old names, kept
working with a warning for one release, were removed in 0.2.0
(``docs/reference/configuration.md#renamed-options``). A command line that still uses one is
refused by :func:`refuse_removed_names` before Hydra composes it (``python -m gripdem.run``:
:mod:`gripdem.run`), in one line naming the old option and its replacement: Hydra would answer
a removed config file (``experiment=fast``) or key (``model.fast_steps``) with a long message
of its own, after nothing gripdem could name.

Files written before the rename (model files whose encoder is ``interaction``, datasets and
saved run configs whose protocol is ``paper`` or that set ``paper_windows``) are data, not
commands: they stay readable (:data:`gripdem.data.protocols.RENAMED_PROTOCOLS`,
:data:`gripdem.models.encoder_options.RENAMED_ENCODERS`)."""

from __future__ import annotations

from collections.abc import Sequence

#: removed option names: old name -> (its replacement, the release that renamed it, the release
#: that removed the old name). ``key=value``: that value of that option (a config file of a
#: group, or a value of a key); ``key``: the key itself, whatever its value.
RENAMED = {
    "experiment=fast": ("experiment=default", "0.1.0", "0.2.0"),
    "model.fast_steps": ("model.train_steps", "0.1.0", "0.2.0"),
    "model=interaction": ("model=contact", "0.1.0", "0.2.0"),
    "model/encoder=interaction": ("model/encoder=contact", "0.1.0", "0.2.0"),
    "model.encoder.name=interaction": ("model.encoder.name=contact", "0.1.0", "0.2.0"),
    "data.protocol=paper": ("data.protocol=in_sample", "0.1.0", "0.2.0"),
    "data.paper_windows": ("data.in_sample_windows", "0.1.0", "0.2.0"),
}
#: a sweeper's search space given on the command line names options after this prefix
_SWEEPER_PARAMS = "hydra.sweeper.params."


def removed_line(old: str) -> str:
    """The line that refuses the removed name ``old`` (a key of :data:`RENAMED`)."""
    new, renamed, removed = RENAMED[old]
    return f"{old} was renamed {new} in gripdem {renamed} and removed in {removed}: use {new}"


def _key(key: str) -> str:
    """An option's key as :data:`RENAMED` writes it: a group's ``/`` and a node's ``.`` alike."""
    if key.startswith(_SWEEPER_PARAMS):
        key = key[len(_SWEEPER_PARAMS) :]
    return key.replace("/", ".")


def _values(override) -> list[str]:
    """The values an override gives (one, or each of a sweep's choices; none for a deletion,
    a range or a glob)."""
    from hydra.core.override_parser.types import ChoiceSweep

    value = override.value()
    items = value.list if isinstance(value, ChoiceSweep) else [value]
    return [str(item) for item in items if isinstance(item, (str, int, float, bool))]


def removed_names(overrides: Sequence[str]) -> list[str]:
    """The removed names (keys of :data:`RENAMED`) that Hydra overrides use, in command-line
    order: a removed key set, added (``+``) or deleted (``~``), or a removed value or config
    file chosen (alone or among a sweep's choices). An override Hydra cannot parse is left to
    Hydra to refuse."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parser = OverridesParser.create()
    found: list[str] = []
    for text in overrides:
        try:
            (override,) = parser.parse_overrides([text])
        except HydraException:
            continue
        key = _key(override.key_or_group)
        values = _values(override)
        for old in RENAMED:
            old_key, _, old_value = old.partition("=")
            if _key(old_key) != key or old in found:
                continue
            if not old_value or old_value in values:
                found.append(old)
    return found


def hydra_overrides(argv: Sequence[str]) -> list[str]:
    """The overrides of a Hydra command line (its flags and their arguments left out), as
    ``@hydra.main`` reads them; empty when Hydra's parser refuses the line (Hydra says why)."""
    if "--version" in argv:  # Hydra prints its version and exits
        return []
    from hydra._internal.utils import get_args_parser

    class _Refused(Exception):
        pass

    def refuse(*args, **kwargs):
        raise _Refused

    parser = get_args_parser()
    parser.error = refuse  # type: ignore[method-assign]  # not printed here: Hydra prints it
    parser.exit = refuse  # type: ignore[method-assign]
    try:
        return list(parser.parse_args(list(argv)).overrides or [])
    except _Refused:
        return []


def refuse_removed_names(argv: Sequence[str]) -> None:
    """Raise ValueError with one line for the removed names a Hydra command line uses (each
    one's :func:`removed_line`, joined by ``;``); nothing when it uses none. Called before
    Hydra composes, so nothing is written (no output folder, no dataset)."""
    found = removed_names(hydra_overrides(argv))
    if found:
        raise ValueError("; ".join(removed_line(old) for old in found))
