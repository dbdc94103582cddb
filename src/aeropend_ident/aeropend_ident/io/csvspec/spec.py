"""The column mapping of a CSV log (:class:`CsvSpec`) and its preset files (YAML).

A preset is one YAML mapping of :class:`CsvSpec` fields (:data:`PRESET_KEYS`, documented in
docs/csv_import.md). The shipped presets (``aeropend_ident/io/presets/*.yaml``, package data) are
:data:`PRESETS`; a lab's own preset file is loaded by path (:func:`load_preset_file`,
``--preset my_rig.yaml``, ``FILE.csv:my_rig.yaml``) and written from command-line flags
(:func:`write_preset_file`, ``csv_import --write-preset my_rig.yaml``). Every file is validated key by
key: a message names the file, the key and what was expected.
"""

from __future__ import annotations

import codecs
import difflib
import fnmatch
import math
from collections.abc import Callable
from dataclasses import InitVar, asdict, dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import yaml

from aeropend_ident.errors import CsvImportError
from aeropend_ident.io.csvspec.input_kinds import INPUT_KINDS, LAWS, InputMap, input_map
from aeropend_sim.contract import EXTRA_CHANNELS, REFERENCE_CHANNEL, ContractError, check_extra_channel
from aeropend_sim.files.safe_yaml import YamlRefusedError, load_yaml, parse_yaml
from aeropend_sim.output_folder import is_fault, write_file_atomically
from aeropend_sim.recording import MEASURED_CHANNELS

__all__ = [
    "PRESETS",
    "PRESET_KEYS",
    "PRESET_SUFFIXES",
    "Column",
    "CsvSpec",
    "find_preset",
    "load_preset_file",
    "load_presets",
    "resolve_preset",
    "spec_from_mapping",
    "spec_to_mapping",
    "write_preset_file",
]

Column = str | int
TimeUnit = Literal["s", "ms", "us", "sample"]
TIME_UNITS: tuple[str, ...] = ("s", "ms", "us", "sample")
#: Suffixes of a preset file given by path (anything else is a shipped preset's name).
PRESET_SUFFIXES = (".yaml", ".yml")
#: Contract channels a CSV column may fill (θ is ``angle_col``).
_CONTRACT_CHANNELS = tuple(c for c in MEASURED_CHANNELS if c != "theta")


@dataclass(frozen=True)
class CsvSpec:
    """How to read one CSV layout.

    Columns are given by header name (exact, case-insensitive, or the name before a unit
    bracket: ``"pwm"`` matches ``"pwm [0-255 analogWrite]"``) or by 0-based index.

    Attributes
    ----------
    angle_col : str or int
        Angle column.
    angle_unit : {"rad", "deg"}
        Unit of the angle column.
    angle_zero : float
        Raw angle reading (column unit) at θ = 0; θ = angle_sign · (raw − angle_zero) [rad].
    angle_sign : float
        +1 or −1 (direction convention).
    time_col : str or int, optional
        Time column; None when the file has none (then ``rate_hz`` gives t = k / rate_hz).
    time_unit : {"s", "ms", "us", "sample"}
        Unit of the time column; ``"sample"`` means a sample index k (t = k / ``rate_hz``).
    rate_hz : float, optional
        Sample rate [Hz] for files without time column or with a sample-index column.
    input_col : str or int, optional
        Actuator command column; None when the file has none (then ``input_constant`` is used,
        checked by :func:`~aeropend_ident.io.csvspec.constant_input.check_constant_input`).
    input_kind : str
        How the command is logged: a key of
        :data:`~aeropend_ident.io.csvspec.input_kinds.INPUT_KINDS` (duty, percent, pwm, voltage,
        pulse_width_ms, pulse_width_us, servo_deg).
    input_offset, input_span : float, optional
        The affine map τ = (x − input_offset) / input_span in the kind's unit (None: the kind's
        default, e.g. span 255 for pwm; pulse widths have none: the ESC's calibrated range).
    input_law : {"linear", "rms"}
        ``rms``: τ = ((x − offset) / span)² (the firmware treats a voltage as an RMS value, e.g.
        AutomationShield's ``actuatorWriteVolt``); voltage only.
    quantize_counts : int, optional
        Round the duty *down* to multiples of 1 / quantize_counts, mimicking a firmware that
        truncates to integer PWM counts (the duty actually applied).
    input_constant : float, optional
        Actuator value (in ``input_kind`` units) when the file has no actuator column.
    reference_col : str or int, optional
        Reference θ_ref of a closed-loop log, in the angle column's unit, zero and sign; stored as
        the extra channel ``theta_ref``, never as the input.
    channels : dict
        Contract channels: name -> (column, scale to SI), e.g. ``{"i_a": ("current [mA]", 1e-3)}``.
    extra_channels : dict
        Channels stored under their own names (:data:`aeropend_sim.contract.EXTRA_CHANNELS`, e.g. the
        second axis ``phi``, or a lab's name): name -> (column, scale to ``unit``, unit).
    delimiter : str, optional
        Field separator; None = auto-detect among ``,`` ``;`` and tab.
    decimal : {".", ","}, optional
        Decimal mark; None = auto-detect (comma only when the separator is not a comma).
    comment : str
        Lines whose first non-blank character starts with this are skipped.
    header : bool, optional
        Whether the first non-comment line is a header; None = auto-detect (a line with a
        non-numeric field).
    encoding : str
        Text encoding (a UTF-8 BOM is stripped).
    name : str
        Spec/preset name (recorded in ``meta``).
    meta : dict
        Provenance / licence notes copied into the recording's ``meta``.
    pwm_full_scale, supply_voltage, voltage_law : InitVar, optional
        Earlier names of ``input_span`` (pwm, voltage) and ``input_law``; accepted by the
        constructor, stored as those.
    """

    angle_col: Column
    angle_unit: Literal["rad", "deg"] = "rad"
    angle_zero: float = 0.0
    angle_sign: float = 1.0
    time_col: Column | None = None
    time_unit: TimeUnit = "s"
    rate_hz: float | None = None
    input_col: Column | None = None
    input_kind: str = "duty"
    input_offset: float | None = None
    input_span: float | None = None
    input_law: str = "linear"
    quantize_counts: int | None = None
    input_constant: float | None = None
    reference_col: Column | None = None
    channels: dict[str, tuple[Column, float]] = field(default_factory=dict)
    extra_channels: dict[str, tuple[Column, float, str]] = field(default_factory=dict)
    delimiter: str | None = None
    decimal: Literal[".", ","] | None = None
    comment: str = "#"
    header: bool | None = None
    encoding: str = "utf-8"
    name: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    pwm_full_scale: InitVar[float | None] = None
    supply_voltage: InitVar[float | None] = None
    voltage_law: InitVar[str | None] = None

    def __post_init__(self, pwm_full_scale: float | None, supply_voltage: float | None,
                      voltage_law: str | None) -> None:
        for old, value, key, target in (("pwm_full_scale", pwm_full_scale, "input_span", "pwm"),
                                        ("supply_voltage", supply_voltage, "input_span", "voltage"),
                                        ("voltage_law", voltage_law, "input_law", "voltage")):
            if value is None or (old == "pwm_full_scale" and self.input_kind != "pwm"):
                continue  # pwm_full_scale was a default of every spec; it applies to pwm only
            current = getattr(self, key)
            if current not in (None, "linear") and current != value:
                raise CsvImportError(f"CsvSpec {self.name or '(custom)'}: {old} = {value!r} and {key} = "
                                     f"{current!r} disagree ({old} is {key} of input_kind {target!r})")
            object.__setattr__(self, key, value)
        units = {k: (c, s, EXTRA_CHANNELS[k][0] if k in EXTRA_CHANNELS and not u else u)
                 for k, (c, s, u) in self.extra_channels.items()}
        object.__setattr__(self, "extra_channels", units)  # an EXTRA_CHANNELS name: its unit

    def input_map(self) -> InputMap:
        """The validated input map of this spec (:func:`~aeropend_ident.io.csvspec.input_kinds.input_map`)."""
        return input_map(self.input_kind, self.input_offset, self.input_span, self.input_law,
                         where=f"CsvSpec {self.name or '(custom)'}")

    def check(self) -> None:
        """Raise :class:`CsvImportError` if the spec is inconsistent (before reading a file)."""
        where = f"CsvSpec {self.name or '(custom)'}"
        if self.angle_unit not in ("rad", "deg"):
            raise CsvImportError(f"{where}: angle_unit {self.angle_unit!r}; expected 'rad' or 'deg'")
        if self.angle_sign not in (1, -1, 1.0, -1.0):
            raise CsvImportError(f"{where}: angle_sign {self.angle_sign!r}; expected +1 or -1")
        if self.time_unit not in TIME_UNITS:
            raise CsvImportError(f"{where}: time_unit {self.time_unit!r}; expected s, ms, us or sample")
        needs_rate = self.time_col is None or self.time_unit == "sample"
        if needs_rate and not (self.rate_hz and self.rate_hz > 0 and math.isfinite(self.rate_hz)):
            raise CsvImportError(f"{where}: rate_hz = {self.rate_hz!r}; a positive sample rate [Hz] is "
                                 "needed when there is no time column or the time column is a sample index")
        self.input_map()
        if self.input_col is None and self.input_constant is None:
            raise CsvImportError(f"{where}: no input column and no input_constant; the actuator command (the "
                                 "duty cycle) is required")
        if self.input_constant is not None and not math.isfinite(self.input_constant):
            raise CsvImportError(f"{where}: input_constant {self.input_constant!r}; expected a finite value")
        if self.reference_col is not None and self.reference_col == self.input_col:
            raise CsvImportError(f"{where}: reference_col and input_col are the same column "
                                 f"{self.input_col!r}; a reference is not an input (log the actuator "
                                 "command)")
        if self.quantize_counts is not None and not (isinstance(self.quantize_counts, int)
                                                     and self.quantize_counts > 0):
            raise CsvImportError(f"{where}: quantize_counts {self.quantize_counts!r}; expected an integer "
                                 "> 0")
        for ch in self.channels:
            if ch not in _CONTRACT_CHANNELS:
                raise CsvImportError(f"{where}: channel {ch!r}; expected one of {list(_CONTRACT_CHANNELS)} "
                                     "(other names go under extra_channels)")
        for ch, (_col, _scale, unit) in self.extra_channels.items():
            if ch == REFERENCE_CHANNEL:
                raise CsvImportError(f"{where}: extra channel {ch!r}: the reference is reference_col (in the "
                                     "angle column's unit, zero and sign)")
            try:
                check_extra_channel(ch, unit)
            except ContractError as exc:
                raise CsvImportError(f"{where}: {exc}") from None
        if self.delimiter is not None and len(self.delimiter) != 1:
            raise CsvImportError(f"{where}: delimiter {self.delimiter!r} must be one character")
        if self.decimal not in (None, ".", ","):
            raise CsvImportError(f"{where}: decimal {self.decimal!r}; expected '.' or ','")
        if self.decimal == "," and self.delimiter == ",":
            raise CsvImportError(f"{where}: decimal comma needs a separator other than ','")


# --------------------------------------------------------------------------------------------
# Preset files
# --------------------------------------------------------------------------------------------

_COLUMN = "a column name (header text) or a 0-based column index"
#: Keys of a preset file and what each expects (the schema; docs/csv_import.md lists it).
PRESET_KEYS: dict[str, str] = {
    "angle_col": f"{_COLUMN} (required): the pendulum angle",
    "angle_unit": "rad or deg",
    "angle_zero": "a number: the raw angle (column unit) at θ = 0 (rod hanging down)",
    "angle_sign": "+1 or -1: θ = angle_sign · (raw − angle_zero)",
    "time_col": f"{_COLUMN}, or null when the file has no time column (then rate_hz)",
    "time_unit": "s, ms, us or sample (a sample index; then rate_hz)",
    "rate_hz": "a sample rate > 0 [Hz] (files without time column or with a sample index)",
    "input_col": f"{_COLUMN}: the actuator command, or null (then input_constant)",
    "input_kind": f"one of {', '.join(INPUT_KINDS)}",
    "input_offset": "a number in the input kind's unit: the logged value at duty 0 (null: the kind's "
                    "default)",
    "input_span": "a number > 0 in the input kind's unit: logged value at full duty minus input_offset "
                  "(null: the kind's default)",
    "input_law": f"{' or '.join(LAWS)} (rms: duty = fraction², voltage only)",
    "quantize_counts": "an integer > 0: round the duty down to multiples of 1/quantize_counts, or null",
    "input_constant": "a number in the input kind's unit: the actuator value of a log without input column "
                      "(a free decay or a step from rest), or null",
    "reference_col": f"{_COLUMN}: the reference θ_ref of a closed loop (angle column's unit), or null",
    "channels": f"a mapping of contract channel ({', '.join(_CONTRACT_CHANNELS)}) to [column, scale to SI]",
    "extra_channels": "a mapping of channel name (phi, phi_dot, thrust or your own) to [column, scale] or "
                      "[column, scale, unit] (the unit is needed for your own names)",
    "delimiter": "one character, 'tab', or null (auto-detect)",
    "decimal": "'.' or ',', or null (auto-detect)",
    "comment": "the text that starts a comment line (default '#')",
    "header": "true, false or null (auto-detect)",
    "encoding": "a text encoding (default utf-8)",
    "name": "the preset's name (default: the file name without .yaml)",
    "meta": "a mapping of notes copied into the recording (provenance, licence, files: [patterns])",
}
#: Earlier keys and the key that replaced them (for the message).
_RENAMED = {"pwm_full_scale": "input_span (counts at full duty) with input_kind: pwm",
            "supply_voltage": "input_span (volts at full command) with input_kind: voltage",
            "voltage_law": "input_law"}


def _is_column(v: Any) -> bool:
    return (isinstance(v, str) and v != "") or (isinstance(v, int) and not isinstance(v, bool) and v >= 0)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))


def _encoding(v: Any) -> bool:
    try:
        codecs.lookup(v)
    except (LookupError, TypeError):
        return False
    return True


#: key -> whether a (non-null) value is acceptable.
_CHECKS: dict[str, Callable[[Any], bool]] = {
    "angle_col": _is_column, "time_col": _is_column, "input_col": _is_column, "reference_col": _is_column,
    "angle_unit": lambda v: v in ("rad", "deg"),
    "angle_zero": _is_number, "input_offset": _is_number, "input_span": _is_number,
    "input_constant": _is_number,
    "angle_sign": lambda v: _is_number(v) and float(v) in (1.0, -1.0),
    "time_unit": lambda v: v in TIME_UNITS,
    "rate_hz": lambda v: _is_number(v) and float(v) > 0,
    "input_kind": lambda v: v in INPUT_KINDS,
    "input_law": lambda v: v in LAWS,
    "quantize_counts": lambda v: isinstance(v, int) and not isinstance(v, bool) and v > 0,
    "delimiter": lambda v: isinstance(v, str) and (len(v) == 1 or v in ("tab", "\\t")),
    "decimal": lambda v: v in (".", ","),
    "comment": lambda v: isinstance(v, str),
    "header": lambda v: isinstance(v, bool),
    "encoding": _encoding,
    "name": lambda v: isinstance(v, str) and v != "",
    "meta": lambda v: isinstance(v, dict),
}
_FLOATS = ("angle_zero", "angle_sign", "rate_hz", "input_offset", "input_span", "input_constant")
#: Keys that may be null (their default is None).
_NULLABLE = ("time_col", "rate_hz", "input_col", "input_offset", "input_span", "quantize_counts",
             "input_constant", "reference_col", "delimiter", "decimal", "header")


def _channel_map(where: str, key: str, value: Any, with_unit: bool) -> dict[str, tuple[Any, ...]]:
    """``channels`` / ``extra_channels``: name -> [column, scale] (or [column, scale, unit])."""
    if not isinstance(value, dict):
        raise CsvImportError(f"{where}: key '{key}': expected {PRESET_KEYS[key]}, got {value!r}")
    out: dict[str, tuple[Any, ...]] = {}
    shape = "[column, scale] or [column, scale, unit]" if with_unit else "[column, scale]"
    for name, entry in value.items():
        ok = isinstance(entry, list) and len(entry) in ((2, 3) if with_unit else (2,)) \
            and _is_column(entry[0]) and _is_number(entry[1]) \
            and (len(entry) == 2 or isinstance(entry[2], str))
        if not ok:
            raise CsvImportError(f"{where}: key '{key}.{name}': expected {shape} (scale a number), got "
                                 f"{entry!r}")
        col, scale = entry[0], float(entry[1])
        if with_unit:
            try:
                unit = check_extra_channel(str(name), entry[2] if len(entry) == 3 else None)
            except ContractError as exc:
                raise CsvImportError(f"{where}: key '{key}.{name}': {exc}") from None
            out[str(name)] = (col, scale, unit)
        else:
            out[str(name)] = (col, scale)
    return out


def spec_from_mapping(data: Any, where: str, name: str | None = None) -> CsvSpec:
    """A :class:`CsvSpec` from a preset file's mapping, validated key by key.

    Parameters
    ----------
    data : Any
        The parsed YAML document.
    where : str
        Prefix of the messages (the file).
    name : str, optional
        The name when the mapping has none (a user file: its stem).

    Raises
    ------
    CsvImportError
        Not a mapping, an unknown key (with the closest known one), a value of the wrong kind
        (naming the key and what it expects) or an inconsistent spec (:meth:`CsvSpec.check`).
    """
    if not isinstance(data, dict):
        keys = ", ".join(list(PRESET_KEYS)[:4])
        raise CsvImportError(f"{where}: expected a mapping of preset keys ({keys}, ...), got "
                             f"{type(data).__name__}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key in _RENAMED:
            raise CsvImportError(f"{where}: key '{key}' is now {_RENAMED[key]}")
        if key not in PRESET_KEYS:
            close = difflib.get_close_matches(str(key), PRESET_KEYS, n=1)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise CsvImportError(f"{where}: unknown key '{key}'; {hint}the keys are {', '.join(PRESET_KEYS)}")
        if key in ("channels", "extra_channels"):
            kwargs[key] = _channel_map(where, key, value, key == "extra_channels")
            continue
        if value is None and key in _NULLABLE:
            kwargs[key] = None
            continue
        if not _CHECKS[key](value):
            raise CsvImportError(f"{where}: key '{key}': expected {PRESET_KEYS[key]}, got {value!r}")
        kwargs[key] = float(value) if key in _FLOATS else value
    if "angle_col" not in kwargs:
        raise CsvImportError(f"{where}: missing key 'angle_col': expected {PRESET_KEYS['angle_col']}")
    if kwargs.get("delimiter") in ("tab", "\\t"):
        kwargs["delimiter"] = "\t"
    kwargs.setdefault("name", name or "")
    spec = CsvSpec(**kwargs)
    try:
        spec.check()
    except CsvImportError as exc:
        raise CsvImportError(f"{where}: {str(exc).split(': ', 1)[-1]}") from None
    return spec


def spec_to_mapping(spec: CsvSpec) -> dict[str, Any]:
    """The preset mapping of a spec: the fields that differ from the defaults, in field order
    (channels as lists), what :func:`spec_from_mapping` reads back to an equal spec."""
    default = CsvSpec(angle_col=0)
    out: dict[str, Any] = {}
    for f in fields(CsvSpec):
        value = getattr(spec, f.name)
        if f.name != "angle_col" and value == getattr(default, f.name):
            continue
        if f.name == "channels":
            value = {k: [c, float(s)] for k, (c, s) in value.items()}
        elif f.name == "extra_channels":
            value = {k: [c, float(s), u] if k not in EXTRA_CHANNELS else [c, float(s)]
                     for k, (c, s, u) in value.items()}
        elif f.name == "delimiter" and value == "\t":
            value = "tab"
        out[f.name] = value
    return out


def load_preset_file(path: str | Path) -> CsvSpec:
    """Load a lab's preset file (same schema as the shipped presets; name defaults to the file's stem).

    Raises
    ------
    CsvImportError
        Missing or unreadable file, invalid YAML (with its line), a YAML alias or a file above the
        size limit (:mod:`aeropend_sim.files.safe_yaml`) or an invalid preset (:func:`spec_from_mapping`).
    """
    path = Path(path)
    try:
        data = load_yaml(path, "a CSV preset")
    except OSError as exc:
        raise CsvImportError(f"preset file {path}: cannot read ({exc.strerror or exc}); expected a YAML "
                             "file with the keys of docs/csv_import.md") from None
    except (YamlRefusedError, UnicodeDecodeError) as exc:
        raise CsvImportError(f"preset file {exc}" if isinstance(exc, YamlRefusedError) else
                             f"preset file {path}: not UTF-8 text ({exc.reason}); expected a YAML file with "
                             "the keys of docs/csv_import.md") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        why = str(getattr(exc, "problem", None) or exc)
        context, start = getattr(exc, "context", None), getattr(exc, "context_mark", None)
        if context and start is not None:
            why += f", {context.replace('while parsing', 'in')} that starts on line {start.line + 1}"
        raise CsvImportError(f"preset file {path}{line}: not valid YAML ({why})") from None
    return spec_from_mapping(data, f"preset file {path}", name=path.stem)


def write_preset_file(spec: CsvSpec, path: str | Path, overwrite: bool = False,
                      comment: str = "") -> Path:
    """Write ``spec`` as a preset file (:func:`spec_to_mapping`), read back by :func:`load_preset_file`.

    Parameters
    ----------
    spec : CsvSpec
        The spec (its ``name`` becomes the file's stem).
    path : str or Path
        ``.yaml`` / ``.yml`` file to create.
    overwrite : bool
        Replace an existing file (never a directory).
    comment : str
        Lines written as a ``#`` comment at the top (e.g. the command line).

    Raises
    ------
    CsvImportError
        Wrong suffix, an existing file without ``overwrite``, a directory, or a write error.
    """
    path = Path(path)
    if path.suffix.lower() not in PRESET_SUFFIXES:
        raise CsvImportError(f"preset file {path}: expected a .yaml or .yml file name")
    if path.is_dir() or (path.exists() and not overwrite):
        raise CsvImportError(f"preset file {path} already exists; choose another name or pass --overwrite")
    data = spec_to_mapping(replace(spec, name=path.stem))
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    text = head + yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100)
    try:
        write_file_atomically(path, text)
    except OSError as exc:
        if is_fault(exc):  # a full disk, a read-only folder: the command's one-line fault report
            raise
        raise CsvImportError(f"preset file {path}: cannot write ({exc.strerror or exc})") from None
    return path


# --------------------------------------------------------------------------------------------
# Shipped presets (the real recordings in shared/data/real, see its README.md)
# --------------------------------------------------------------------------------------------


def load_presets() -> dict[str, CsvSpec]:
    """The shipped presets: one YAML file per preset in ``aeropend_ident/io/presets/``.

    Read with :mod:`importlib.resources` (package data) and validated like a lab's file.

    Returns
    -------
    dict of str -> CsvSpec
        Preset name (the file's ``name``) -> spec, in file-name order.

    Raises
    ------
    CsvImportError
        An invalid preset file or one whose ``name`` is not its file name.
    """
    folder = resources.files("aeropend_ident.io") / "presets"
    presets: dict[str, CsvSpec] = {}
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if not entry.name.endswith(".yaml"):
            continue
        data = parse_yaml(entry.read_text(encoding="utf-8"), f"preset file {entry.name}", "a CSV preset")
        stem = entry.name[: -len(".yaml")]
        if not isinstance(data, dict) or data.get("name") != stem:
            raise CsvImportError(f"preset file {entry.name}: expected a mapping whose name is the file name")
        presets[stem] = spec_from_mapping(data, f"preset file {entry.name}")
    return presets


#: The shipped presets (:func:`load_presets`), by name.
PRESETS: dict[str, CsvSpec] = load_presets()


def find_preset(path: str | Path) -> str | None:
    """Name of the shipped preset whose ``meta["files"]`` patterns match ``path``'s file name, if any."""
    name = Path(path).name
    if name.endswith(".gz"):
        name = name[:-3]
    for key, spec in PRESETS.items():
        if any(fnmatch.fnmatch(name, pat) for pat in spec.meta.get("files", [])):
            return key
    return None


def is_preset_file(text: str | Path) -> bool:
    """Whether a ``--preset`` value names a preset file (``.yaml`` / ``.yml``), not a shipped preset."""
    return Path(str(text)).suffix.lower() in PRESET_SUFFIXES


def resolve_preset(text: str | Path) -> CsvSpec:
    """The spec of a ``--preset`` value: a shipped preset's name or a preset file's path.

    Raises
    ------
    CsvImportError
        An unknown name (listing the shipped presets) or an invalid file.
    """
    if is_preset_file(text):
        return load_preset_file(text)
    if str(text) not in PRESETS:
        raise CsvImportError(f"unknown preset {str(text)!r}; available: {sorted(PRESETS)} (or a preset "
                             "file: my_rig.yaml)")
    return PRESETS[str(text)]


def spec_summary(spec: CsvSpec) -> dict[str, Any]:
    """``asdict`` of a spec without its ``meta`` (what a recording's ``meta["spec"]`` holds)."""
    return {k: v for k, v in asdict(spec).items() if k != "meta"}

