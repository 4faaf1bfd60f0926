"""The planner's levers as users give them, turned into one `PlannerConfig`.

A lever is a field of `PlannerConfig` (all but `asm`, which the commands take as --asm and
--asms), named by its field name, plus `asm_settings`: "lmjx" (the defaults) or "paper"
(`PlannerConfig.paper()`: the ASMs as the paper states them), applied before the other keys.
Users give them in a TOML file of `KEY = VALUE` lines (`--planner-config FILE`), as
`--set KEY=VALUE` on the command line, or as a mapping (`lmjx.plan_task(planner=...)`).
Every value is checked here against its field's type, bounds and choices (the field's
metadata), and the whole configuration by `PlannerConfig.validate`; a mistake is one line
that names the key and the fix.  `levers_text` lists every key with its default and meaning
(`lmjx plan --help-levers`, docs/PLANNER.md).  Nothing here plans.
"""

from __future__ import annotations

import difflib
import math
import textwrap
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from lmjx.errors import ConfigError
from lmjx.types import PlannerConfig

PRESET = "asm_settings"  # the key that chooses the ASM settings the other keys start from
ASM_SETTINGS = ("lmjx", "paper")
PRESET_MEANING = (
    "lmjx: the ASMs with lmjx's refinements (the defaults below); paper: the ASMs as the paper states them "
    "(futile_filter, path_score, lazy_fallback, lazy_cap and turn_edges false, greedy_fraction 0.25, push_weight 0, "
    "rescore_top 0), applied before the other keys"
)
NOT_LEVERS = {
    "asm": "choose the ASM with --asm (lmjx evaluate: --asms)",
    "max_planning_s": "the planning limit counts simulated control steps, not seconds: set max_sim_steps",
}
TRUE, FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")


def keys() -> list[str]:
    """Every lever's key, in PlannerConfig's order after `asm_settings`."""
    return [PRESET, *(f.name for f in fields(PlannerConfig) if f.name not in NOT_LEVERS)]


def _field_types() -> dict[str, tuple[type, bool]]:
    """Per field: its value type (bool, int, float or str) and whether it may be None."""
    out = {}
    for name, hint in typing.get_type_hints(PlannerConfig).items():
        args = typing.get_args(hint)
        base = next(a for a in args if a is not type(None)) if args else hint
        out[name] = (base, type(None) in args)
    return out


_TYPES = _field_types()
_METADATA = {f.name: f.metadata for f in fields(PlannerConfig)}


def _takes(key: str) -> str:
    """What `key` takes, in words."""
    if key == PRESET:
        return " or ".join(ASM_SETTINGS)
    base, optional = _TYPES[key]
    meta = _METADATA[key]
    if "choices" in meta:
        what = " or ".join(meta["choices"])
    elif base is bool:
        what = "true or false"
    else:
        what = "a whole number" if base is int else "a number"
        if "above" in meta:
            what += f" above {meta['above']:g}" + (f" and at most {meta['most']:g}" if "most" in meta else "")
        elif "least" in meta:
            what += f" at least {meta['least']:g}"
    return what + (" (or none)" if optional else "")


def _unknown(key: str, where: str) -> ConfigError:
    if key in NOT_LEVERS:
        return ConfigError(f"{where}: {key} is not a lever: {NOT_LEVERS[key]}")
    close = difflib.get_close_matches(key, keys(), n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    return ConfigError(f"{where}: unknown key '{key}'{hint}; lmjx plan --help-levers lists the keys")


def check_value(key: str, value: Any, where: str, given: str | None = None) -> Any:
    """`value` for `key` as PlannerConfig holds it (an int given for a number becomes a float;
    the string "none" for a key that may be none becomes None), or a one-line ConfigError
    (saying what was `given`, default the value's repr)."""
    if (key != PRESET and key not in _TYPES) or key in NOT_LEVERS:
        raise _unknown(key, where)
    wrong = ConfigError(f"{where}: {key} takes {_takes(key)}, got {given if given is not None else repr(value)}")
    if key == PRESET:
        if value not in ASM_SETTINGS:
            raise wrong
        return value
    base, optional = _TYPES[key]
    if value is None or (optional and isinstance(value, str) and value.lower() == "none"):
        if not optional:
            raise wrong
        return None
    if base is bool:
        if not isinstance(value, bool):
            raise wrong
    elif base is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise wrong
    elif base is float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise wrong
        value = float(value)
    elif not isinstance(value, str):
        raise wrong
    meta = _METADATA[key]
    if "choices" in meta and value not in meta["choices"]:
        raise wrong
    if "least" in meta and value < meta["least"]:
        raise wrong
    if "above" in meta and not (value > meta["above"] and value <= meta.get("most", math.inf)):
        raise wrong
    return value


def _from_text(key: str, text: str, where: str) -> Any:
    """A --set value, read as its key's type."""
    if (key != PRESET and key not in _TYPES) or key in NOT_LEVERS:
        raise _unknown(key, where)
    base = str if key == PRESET else _TYPES[key][0]
    word = text.strip()
    if key != PRESET and _TYPES[key][1] and word.lower() == "none":
        return None
    try:
        if base is bool:
            if word.lower() not in TRUE + FALSE:
                raise ValueError
            return word.lower() in TRUE
        if base is int:
            return int(word)
        if base is float:
            return float(word)
    except ValueError:
        raise ConfigError(f"{where}: {key} takes {_takes(key)}, got '{text}'") from None
    return word


def parse_sets(items: Sequence[str]) -> dict[str, Any]:
    """`--set KEY=VALUE` items as checked values (a key set twice: the last)."""
    out: dict[str, Any] = {}
    for item in items:
        key, eq, text = item.partition("=")
        where = f"--set {item}"
        if not eq or not key.strip():
            raise ConfigError(f"{where}: give KEY=VALUE, e.g. --set push_weight=0.5 (lmjx plan --help-levers)")
        key = key.strip()
        out[key] = check_value(key, _from_text(key, text, where), where, given=f"'{text}'")
    return out


def read_levers(path: str | Path) -> dict[str, Any]:
    """The levers of a TOML file of `KEY = VALUE` lines, checked."""
    where = f"--planner-config {path}"
    try:
        data = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"{where}: no such file; give a TOML file of KEY = VALUE lines") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{where}: cannot be read ({type(e).__name__}); give a readable TOML file") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: not TOML ({e}); write KEY = VALUE lines, e.g. push_weight = 0.5") from None
    return check_levers(data, where)


def check_levers(levers: Mapping[str, Any], where: str = "planner") -> dict[str, Any]:
    """A mapping of levers, each checked (`check_value`)."""
    return {str(k): check_value(str(k), v, where) for k, v in levers.items()}


def planner_config(asm: str, sim: str, levers: Mapping[str, Any] | None = None) -> PlannerConfig:
    """The planner's configuration for `asm`, planning with the simulator `sim` ("cpu",
    "cpu-near", "gpu"; Random's "none" counts as "cpu"): PlannerConfig's defaults with Greedy's
    candidates chosen for the simulator (`DEFAULT_CANDIDATES`), the paper's settings where
    `asm_settings` is "paper", then every other key of `levers` (checked values), validated."""
    from lmjx.planner.trial import DEFAULT_CANDIDATES

    rest = dict(levers or {})
    preset = rest.pop(PRESET, "lmjx")
    config = PlannerConfig(asm=asm, greedy_candidates=DEFAULT_CANDIDATES[sim if sim != "none" else "cpu"])
    if preset == "paper":
        config = config.paper()
    config = replace(config, **rest)
    config.validate()
    return config


def toml_text(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return f"{value:g}" if isinstance(value, float) else str(value)


def levers_text(width: int = 80) -> str:
    """Every lever with its default and meaning, for `--help-levers`."""
    head = (
        "The planner's levers (lmjx plan, lmjx evaluate): set a key with --set KEY=VALUE (repeatable) or in a "
        "TOML file of KEY = VALUE lines given with --planner-config FILE.  --set wins over the file, and "
        "--candidates and --max-actions over both.  A key that may be none takes the word none.  The results "
        "record the levers (asm_settings in results.json and in plan --json)."
    )
    lines = [*textwrap.wrap(head, width), ""]
    defaults = {f.name: f.default for f in fields(PlannerConfig)}
    for key in keys():
        meaning = PRESET_MEANING if key == PRESET else _METADATA[key]["meaning"]
        default = "lmjx" if key == PRESET else defaults[key]
        lines.append(f"{key} = {toml_text(default)}")
        lines += textwrap.wrap(f"{meaning}; takes {_takes(key)}", width, initial_indent="    ",
                               subsequent_indent="    ")  # fmt: skip
    return "\n".join(lines)
