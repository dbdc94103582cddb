"""Inputs as labs log them (issue 36 item 2): input kinds, user preset files, extra channels, and the
refusal of a constant input that cannot explain a log (a reference is not an input)."""

from __future__ import annotations

import hashlib
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from aeropend_ident.cli.csv_import import build_parser, main
from aeropend_ident.errors import ConstantInputWarning, CsvImportError
from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.bags import read_bag
from aeropend_ident.io.csv_import import PRESETS, CsvSpec, find_preset, import_csv
from aeropend_ident.io.csvspec.constant_input import check_constant_input
from aeropend_ident.io.csvspec.input_kinds import INPUT_KINDS, input_map
from aeropend_ident.io.csvspec.spec import PRESET_KEYS, load_preset_file, spec_to_mapping
from aeropend_ident.io.recording_input import ignored_channels, load_recording
from aeropend_ident.io.resampling import grid_step, regular_sampling, uniform_recording
from aeropend_sim.contract import EXTRA_CHANNELS
from aeropend_sim.recording import Recording, RecordingError

ROOT = Path(__file__).resolve().parents[3]
REAL = ROOT.parent / "shared" / "data" / "real"
ETCHE = REAL / "BA-Etchepareborda__adaptive-control-aeropendulum"
DONDI = REAL / "dondi01__quanser_aero2_project"
real_data = pytest.mark.skipif(not REAL.is_dir(), reason=f"real recordings not found at {REAL}")


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# ------------------------------------------------------------------ input kinds


#: kind, offset, span, logged values, the duty each maps to (exact), values below / above the range.
KIND_CASES = [
    ("duty", None, None, [0.0, 0.25, 1.0, 1.5], [0.0, 0.25, 1.0, 1.0], 0, 1),
    ("percent", None, None, [-5.0, 0.0, 50.0, 100.0], [0.0, 0.0, 0.5, 1.0], 1, 0),
    ("pwm", None, None, [0.0, 51.0, 255.0, 300.0], [0.0, 0.2, 1.0, 1.0], 0, 1),
    ("pwm", None, 1023.0, [0.0, 512.0, 1023.0], [0.0, 512.0 / 1023.0, 1.0], 0, 0),
    ("voltage", None, 12.0, [0.0, 6.0, 12.0, 13.0], [0.0, 0.5, 1.0, 1.0], 0, 1),
    ("pulse_width_us", 1100.0, 1200.0, [1000.0, 1100.0, 1400.0, 1700.0, 2300.0, 2400.0],
     [0.0, 0.0, 0.25, 0.5, 1.0, 1.0], 1, 1),
    ("pulse_width_ms", 1.0, 1.0, [0.9, 1.0, 1.25, 1.5, 2.0, 2.1], [0.0, 0.0, 0.25, 0.5, 1.0, 1.0], 1, 1),
    ("servo_deg", None, None, [0.0, 45.0, 90.0, 180.0, 200.0], [0.0, 0.25, 0.5, 1.0, 1.0], 0, 1),
    ("servo_deg", 30.0, 120.0, [0.0, 30.0, 90.0, 150.0], [0.0, 0.0, 0.5, 1.0], 1, 0),
]


@pytest.mark.parametrize(("kind", "offset", "span", "x", "tau", "below", "above"), KIND_CASES)
def test_each_input_kind_maps_known_values_exactly(tmp_path: Path, kind: str, offset: float | None,
                                                   span: float | None, x: list[float], tau: list[float],
                                                   below: int, above: int) -> None:
    rows = "".join(f"{0.01 * k:.2f},{v!r},0.0\n" for k, v in enumerate(x))
    path = _write(tmp_path / "log.csv", "t,x,a\n" + rows)
    spec = CsvSpec(time_col="t", input_col="x", input_kind=kind, input_offset=offset, input_span=span,
                   angle_col="a")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the clipping warning, counted below
        rec = import_csv(path, spec)
    assert rec.duty.tolist() == tau
    assert rec.meta["duty_clipped"] == {"below_0": below, "above_1": above}
    assert rec.meta["input_map"].endswith(f"({kind})")


def test_esc_pulse_width_as_a_lab_states_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An ESC calibrated to 1.1-2.3 ms: below the arming pulse is duty 0 (counted), not an error."""
    m = input_map("pulse_width_ms", 1.1, 1.2)
    tau, below, above = m.duty(np.array([0.9, 1.1, 1.4, 1.7, 2.0, 2.3, 2.35]))
    assert tau == pytest.approx([0.0, 0.0, 0.25, 0.5, 0.75, 1.0, 1.0], abs=1e-15)  # 1.1, 1.2: not binary
    assert (below, above) == (1, 1)
    assert m.describe() == "τ = (x − 1.1 ms) / 1.2 ms, clipped to [0, 1] (pulse_width_ms)"
    rows = "t,pw [ms],angle [deg]\n" + "".join(f"{0.02 * k:.2f},{1.0 + 0.01 * k:.2f},{k}\n"
                                                for k in range(150))
    path = _write(tmp_path / "esc.csv", rows)
    assert main([str(path), "--time-col", "t", "--input-col", "pw", "--input-kind", "pulse_width_ms",
                 "--input-offset", "1.1", "--input-span", "1.2", "--angle-col", "angle",
                 "--angle-unit", "deg"]) == 0
    out = capsys.readouterr().out
    assert "input τ = (x − 1.1 ms) / 1.2 ms" in out and "duty 0.0000..1.0000" in out
    assert "29 duty value(s) clipped" in out  # 1.00-1.09 ms (10 rows: duty 0) and 2.31-2.49 ms (19: duty 1)


def test_input_map_validation_names_the_key() -> None:
    with pytest.raises(CsvImportError, match=r"input_kind 'pulse_width_ms' needs input_offset \[ms\]: the "
                                             r"pulse width at zero throttle"):
        input_map("pulse_width_ms")
    with pytest.raises(CsvImportError, match=r"range at 1100-2300 ms, outside 0-20 ms \(in us\? that is "
                                             r"input_kind 'pulse_width_us'\)"):
        input_map("pulse_width_ms", 1100, 1200)
    with pytest.raises(CsvImportError, match=r"input_span = 0 counts: expected > 0"):
        input_map("pwm", 0, 0)
    with pytest.raises(CsvImportError, match=r"input_law 'rms': input_kind 'pwm' takes linear"):
        input_map("pwm", law="rms")
    with pytest.raises(CsvImportError, match=r"range at 0-200 deg, outside 0-180 deg"):
        input_map("servo_deg", 0, 200)


def test_input_kinds_have_one_home() -> None:
    """The CLI's --input-kind choices, the preset schema and docs/csv_import.md read INPUT_KINDS."""
    action = next(a for a in build_parser()._actions if a.dest == "input_kind")
    assert list(action.choices) == list(INPUT_KINDS)
    assert all(k in PRESET_KEYS["input_kind"] for k in INPUT_KINDS)
    doc = (ROOT / "docs" / "csv_import.md").read_text(encoding="utf-8")
    rows = {ln.split("|")[1].strip().strip("`"): [c.strip() for c in ln.split("|")[2:6]]
            for ln in doc.splitlines() if ln.startswith("| `")}
    for kind in INPUT_KINDS.values():  # the docs' table says what the registry says
        unit, offset, span, bounds = rows[kind.name]
        assert unit == kind.unit, kind.name
        assert offset == ("required" if kind.offset is None else f"{kind.offset:g}"), kind.name
        assert span == ("required" if kind.span is None else f"{kind.span:g}"), kind.name
        assert bounds == ("—" if kind.bounds is None else f"{kind.bounds[0]:g}–{kind.bounds[1]:g}"), kind.name
    for key in PRESET_KEYS:
        assert f"| `{key}` |" in doc, key


# ------------------------------------------------------------------ user preset files


ESC_LOG = "t [s],pw [ms],angle [deg],ref [deg],yaw [deg],F [g],T [C]\n" + "".join(
    f"{0.01 * k:.2f},{1.1 + 0.6 * (1 + math.sin(0.05 * k)) / 2:.4f},{-90 + 20 * math.sin(0.03 * k):.3f},"
    f"{-90 + 20 * (k // 100 % 2):.1f},{5 * math.cos(0.02 * k):.3f},{40 + 10 * math.sin(0.05 * k):.2f},"
    f"{25 + 0.01 * k:.2f}\n" for k in range(400))
ESC_FLAGS = ["--time-col", "t [s]", "--input-col", "pw", "--input-kind", "pulse_width_ms",
             "--input-offset", "1.1", "--input-span", "1.2", "--angle-col", "angle", "--angle-unit", "deg",
             "--angle-zero", "-90",
             "--reference-col", "ref", "--channel", "phi=yaw:0.017453292519943295",
             "--channel", "thrust=F:0.00980665", "--channel", "motor_temp=T [C]:1:degC"]


def _same(a: Recording, b: Recording) -> None:
    """Equal recordings (a bag keeps t to 0.5 ns and i_a, v_a as float32, the rest bit-exactly)."""
    assert np.max(np.abs(a.t - b.t)) <= 0.5e-9 and np.array_equal(a.duty, b.duty)
    assert sorted(a.channels) == sorted(b.channels) and sorted(a.extra) == sorted(b.extra)
    for k in a.channels:
        if k in ("i_a", "v_a"):
            assert np.array_equal(a.channels[k].astype(np.float32), b.channels[k].astype(np.float32)), k
            continue
        assert np.array_equal(a.channels[k], b.channels[k], equal_nan=True), k
    for k in a.extra:
        assert np.array_equal(a.extra[k], b.extra[k], equal_nan=True), k
    assert a.extra_units == b.extra_units


def test_write_preset_then_import_gives_identical_recordings(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    log = _write(tmp_path / "esc_run.csv", ESC_LOG)
    preset = tmp_path / "my_rig.yaml"
    assert main([str(log), *ESC_FLAGS, "--write-preset", str(preset), "-o", str(tmp_path / "bag1")]) == 0
    assert f"Wrote preset {preset}" in capsys.readouterr().out
    data = yaml.safe_load(preset.read_text(encoding="utf-8"))
    assert data["name"] == "my_rig" and data["input_kind"] == "pulse_width_ms"
    assert (data["input_offset"], data["input_span"]) == (1.1, 1.2)
    assert data["reference_col"] == "ref" and data["angle_zero"] == -90.0
    assert data["extra_channels"] == {"phi": ["yaw", 0.017453292519943295], "thrust": ["F", 0.00980665],
                                      "motor_temp": ["T [C]", 1.0, "degC"]}
    head = "# csv_import preset 'my_rig' (schema: docs/csv_import.md)"
    assert preset.read_text(encoding="utf-8").startswith(head)
    # the preset alone reproduces the recording, in Python, on the command line and as FILE.csv:preset.yaml
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        first = import_csv(log, load_preset_file(preset))
        by_path = import_csv(log, str(preset))
        by_arg = load_recording(f"{log}:{preset}")
        by_default = load_recording(log, preset=str(preset))
    assert main([str(log), "--preset", str(preset), "-o", str(tmp_path / "bag2")]) == 0
    for other in (by_path, by_arg, by_default):
        _same(first, other)
    _same(read_bag(tmp_path / "bag1"), read_bag(tmp_path / "bag2"))
    # the numbers: duty of the pulse width, reference and φ in the angle's / their own frame
    pw = np.array([float(r.split(",")[1]) for r in ESC_LOG.splitlines()[1:]])
    assert first.duty == pytest.approx(np.clip((pw - 1.1) / 1.2, 0, 1), abs=1e-15)
    assert set(np.round(first.extra["theta_ref"], 12)) == {0.0, round(math.radians(20.0), 12)}
    assert first.extra_units == {"theta_ref": "rad", "phi": "rad", "thrust": "N", "motor_temp": "degC"}
    assert first.extra["thrust"][0] == pytest.approx(0.4 * 0.00980665 * 100, rel=1e-12)
    # a second write needs --overwrite; a refused run leaves the file as it was
    before = preset.read_text(encoding="utf-8")
    assert main([str(log), *ESC_FLAGS, "--write-preset", str(preset)]) == 1
    assert "already exists" in capsys.readouterr().err and preset.read_text(encoding="utf-8") == before


@real_data
@pytest.mark.real_data
def test_shipped_preset_round_trips_through_a_user_file(tmp_path: Path) -> None:
    """Every shipped preset written as a user file reads back as the same spec (bar its name)."""
    for name, spec in PRESETS.items():
        path = tmp_path / f"copy_{name}.yaml"
        path.write_text(yaml.safe_dump(spec_to_mapping(spec) | {"name": f"copy_{name}"}, sort_keys=False),
                        encoding="utf-8")
        back = load_preset_file(path)
        assert spec_to_mapping(back) | {"name": name} == spec_to_mapping(spec), name


@pytest.mark.parametrize(("text", "message"), [
    ("- angle_col: a\n", r"expected a mapping of preset keys \(angle_col, angle_unit, angle_zero, "
                         r"angle_sign, \.\.\.\), got list"),
    ("input_col: u\n", r"missing key 'angle_col': expected a column name"),
    ("angle_col: a\ninput_col: u\nangle_unit: degrees\n",
     r"key 'angle_unit': expected rad or deg, got 'degrees'"),
    ("angle_col: a\ninput_col: u\ninput_kind: pulse_width\n",
     r"key 'input_kind': expected one of duty, percent, pwm, voltage, pulse_width_ms"),
    ("angle_col: a\ninput_col: u\ninput_kind: voltage\nsupply_voltage: 12\n",
     r"key 'supply_voltage' is now input_span \(volts at full command\) with input_kind: voltage"),
    ("angle_col: a\ninput_col: u\nextra_channels:\n  x_acc: [ax, 1.0]\n",
     r"key 'extra_channels.x_acc': extra channel 'x_acc': its unit is needed"),
    ("angle_col: a\ninput_col: u\nextra_channels:\n  phi: [yaw, 1.0, deg]\n",
     r"key 'extra_channels.phi': extra channel 'phi' is in rad .* not 'deg'; scale the column to rad"),
    ("angle_col: a\ninput_col: u\nchannels:\n  i_a: current\n",
     r"key 'channels.i_a': expected \[column, scale\]"),
    ("angle_col: a\ninput_col: u\nrate_hz: -70\n", r"key 'rate_hz': expected a sample rate > 0 \[Hz\]"),
    ("angle_col: a\ninput_col: u\nreference_col: u\n",
     r"reference_col and input_col are the same column 'u'; a reference is not an input"),
])
def test_bad_preset_file_names_key_and_expectation(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path / "lab.yaml", text if text.startswith("-") else "time_col: t\n" + text)
    with pytest.raises(CsvImportError, match=rf"^preset file {re.escape(str(path))}: {message}"):
        load_preset_file(path)


# ------------------------------------------------------------------ extra channels on real recordings


@real_data
@pytest.mark.real_data
def test_quanser_second_axis_and_accelerometer_survive_the_bag(tmp_path: Path) -> None:
    rec = import_csv(DONDI / "SATURATION_ANGLE.csv", "dondi01_aero2")
    assert sorted(rec.extra) == ["phi", "x_acc", "z_acc"]
    assert rec.extra_units == {"phi": "rad", "x_acc": "m/s^2", "z_acc": "m/s^2"}
    # README: yaw locked in this 1-DOF run (reads 0 within 0.003 rad); accelerometer about -7.4, 6.6 m/s^2
    assert rec.extra["phi"].min() == -0.00153398 and rec.extra["phi"].max() == 0.00306796
    assert rec.extra["x_acc"][0] == -7.43916 and rec.extra["z_acc"][0] == 6.60207
    for storage in ("mcap", "sqlite3"):
        back = read_bag(write_bag(rec, tmp_path / storage, storage=storage))
        _same(rec, back)
        assert back.meta["message_counts"]["/aeropend/extra_channels"] == len(rec)
    assert read_bag(tmp_path / "mcap", decoder="typestore").extra["phi"].tolist() == rec.extra["phi"].tolist()


@real_data
@pytest.mark.real_data
@pytest.mark.parametrize(("name", "levels"), [
    ("closedloop_IMC_reference_steps.csv", {0.35, 0.45, 0.5, 0.6, 0.65, 0.8}),
    ("closedloop_STR_load_change.csv", {0.4, 0.7, 0.9})])
def test_closed_loop_reference_is_a_channel_not_the_input(tmp_path: Path, name: str,
                                                          levels: set[float]) -> None:
    assert find_preset(ETCHE / name) == "etchepareborda_closedloop"
    rec = import_csv(ETCHE / name, "etchepareborda_closedloop")
    assert set(np.unique(rec.extra["theta_ref"]).tolist()) == levels  # data README section 6
    assert rec.meta["columns"]["input"] == "pwm [0-255]"
    assert rec.meta["columns"]["theta_ref"] == "theta_ref [rad]"
    open_loop = import_csv(ETCHE / name, "etchepareborda_openloop")  # the same duty and θ as before
    assert np.array_equal(rec.duty, open_loop.duty) and np.array_equal(rec.channels["theta"],
                                                                       open_loop.channels["theta"])
    bag = write_bag(rec, tmp_path / "bag")
    back = load_recording(bag)
    _same(rec, back)
    assert back.meta["message_counts"]["/aeropend/reference"] == len(rec)
    assert "theta_ref" in uniform_recording(back).extra
    assert ignored_channels([back], "θ and the duty cycle") == (
        "ignored channels (not used by this tool; it uses θ and the duty cycle): theta_ref [rad] "
        f"(in {name})")


def test_a_reference_published_when_it_changes_holds_in_the_bag(tmp_path: Path) -> None:
    """A reference logged only where it changes (a live controller's topic): each message belongs to its
    nearest sample and holds until the next (latest wins); a lab channel's unit travels in the label."""
    t = np.arange(8) * 0.01
    ref = np.array([0.2, np.nan, np.nan, 0.4, np.nan, np.nan, 0.3, np.nan])
    rec = Recording(t=t, duty=np.full(8, 0.3), channels={"theta": t}, source="s",
                    extra={"theta_ref": ref, "x_acc": np.arange(8.0)}, extra_units={"x_acc": "m/s^2"})
    back = read_bag(write_bag(rec, tmp_path / "bag"))
    assert back.extra["theta_ref"].tolist() == [0.2, 0.2, 0.2, 0.4, 0.4, 0.4, 0.3, 0.3]
    assert back.meta["message_counts"]["/aeropend/reference"] == 3
    from aeropend_ident.io.bag_codec import decode_float64_array, encode_float64_array

    raw = encode_float64_array(np.array([[1.5, 2.5]]), ["thrust", "x_acc"], ["N", "m/s^2"])
    assert list(decode_float64_array(raw).columns) == ["thrust [N]", "x_acc [m/s^2]"]


def test_extra_channels_travel_with_slices_and_resampling() -> None:
    t = np.array([0.0, 0.01, 0.02, 0.035, 0.04])
    rec = Recording(t=t, duty=np.full(5, 0.3), channels={"theta": t}, source="s",
                    extra={"theta_ref": np.array([0.1, 0.1, 0.5, 0.5, 0.5]), "thrust": 10 * t})
    part = rec.slice(1, 4)
    assert part.extra["theta_ref"].tolist() == [0.1, 0.5, 0.5] and part.extra_units["thrust"] == "N"
    uni = uniform_recording(rec)
    assert uni.t.tolist() == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04])
    assert uni.extra["theta_ref"].tolist() == [0.1, 0.1, 0.5, 0.5, 0.5]  # a set point holds
    assert uni.extra["thrust"] == pytest.approx(10 * uni.t)  # a measurement is interpolated
    with pytest.raises(RecordingError, match="extra channel 'x_acc': its unit is needed"):
        Recording(t=t, duty=t, channels={"theta": t}, extra={"x_acc": t})
    with pytest.raises(RecordingError, match="extra channel 'i_a' is a contract channel"):
        Recording(t=t, duty=t, channels={"theta": t}, extra={"i_a": t}, extra_units={"i_a": "A"})
    assert set(EXTRA_CHANNELS) == {"phi", "phi_dot", "theta_ref", "thrust"}


def test_a_loggers_uneven_timing_is_not_called_dropped_rows() -> None:
    """A ~600 Hz logger that writes every 1 ms or every 3 ms (issue 60: a lab's step tests) has no
    dropped rows: a third of its intervals are 3 ms. The note says uneven timing and counts the
    grid samples filled between them; a log that lost 3 of 1500 rows still says dropped rows."""
    from aeropend_ident.io.resampling import UNEVEN_SHARE

    rng = np.random.default_rng(5)
    steps = rng.choice([1e-3, 3e-3], size=6000, p=[2 / 3, 1 / 3])
    t = np.concatenate([[0.0], np.cumsum(steps)])
    rec = Recording(t=t, duty=np.full(t.size, 0.5), channels={"theta": np.sin(t)}, source="logger600.csv")
    res = uniform_recording(rec).meta["resampling"]
    assert res["dt_s"] == pytest.approx(1e-3) and res["uneven_timing"] is True
    assert res["long_interval_share"] == pytest.approx(1 / 3, abs=0.03)
    assert res["long_interval_share"] > UNEVEN_SHARE
    assert res["dropped_rows"] == int(np.sum(steps > 2e-3)) * 2
    assert "dropped row" not in res["note"].replace("not dropped rows", "")
    assert f"uneven timing: {res['long_interval_share']:.0%} of the intervals are 1.5-5 grid steps long" \
        in res["note"]
    k = np.arange(1500) * 0.02
    keep = np.ones(k.size, bool)
    keep[[200, 700, 701]] = False
    lost = Recording(t=k[keep], duty=np.full(keep.sum(), 0.5), channels={"theta": np.sin(k[keep])},
                     source="lost.csv")
    res = uniform_recording(lost).meta["resampling"]
    assert res["uneven_timing"] is False and "3 dropped row(s) filled" in res["note"]


def test_host_stamp_jitter_keeps_each_row_on_its_own_sample() -> None:
    """A timer-driven rig at 50 Hz whose host stamps each row when it arrives (σ 4 % of the period,
    the first stamp late like any other): row k is the command of sample k. Holding the last row at
    or before each grid instant gave about half the rows to the next instant (a command one whole
    sample, 20 ms, late: an input delay the fits read); the nearest row within half a period keeps
    every command on its sample, and the grid sits where the stamps scatter about."""
    rng = np.random.default_rng(3)
    T, n = 0.02048, 1500
    k = np.arange(n)
    stamps = k * T + rng.normal(0.0, 0.04 * T, n)
    stamps[0] = 0.1 * T  # the first row arrives 2 ms late
    duty = rng.uniform(0.3, 0.7, n)  # a closed loop's command: a new value every sample
    theta = np.sin(0.5 * k * T)  # sampled by the rig's timer at k*T
    keep = np.ones(n, bool)
    keep[[200, 700, 701]] = False  # dropped rows: their slots hold the command before them
    rec = Recording(t=stamps[keep], duty=duty[keep], channels={"theta": theta[keep]}, source="host")
    uni = uniform_recording(rec)
    assert uni.t.size == n and np.allclose(np.diff(uni.t), uni.t[1])
    assert uni.t[1] == pytest.approx(T, rel=2e-3)
    expect = duty.copy()
    expect[200], expect[700], expect[701] = duty[199], duty[699], duty[699]
    assert np.array_equal(uni.duty, expect)
    # the measurements sit on the rig's sample instants, not shifted by the first stamp's lateness:
    # the least-squares time shift of the resampled θ against the true one (a grid through the first
    # stamp: 0.1 T)
    rate = 0.5 * np.cos(0.5 * k * T)
    shift = float(np.sum((uni.channels["theta"] - theta) * rate) / np.sum(rate**2))
    assert abs(shift) < 0.01 * T
    # ... and each is its row's own, beside its command (interpolating from the stamps moved θ by
    # θ̇·δt, up to 0.4 mrad here); over a dropped row, the straight line between the slots around it
    got = uni.channels["theta"]
    assert np.array_equal(got[keep], theta[keep])
    assert got[200] == pytest.approx(0.5 * (theta[199] + theta[201]), abs=1e-15)
    assert got[701] == pytest.approx((theta[699] + 2 * theta[702]) / 3, abs=1e-15)


def test_a_period_imposed_from_another_recording_resamples_the_rows_instants() -> None:
    """Millisecond stamps of a 16.33 ms period (median interval 16 ms) put on a 16 ms grid imposed
    from another recording: each grid instant takes θ from the rows' regular instants, not from
    their stamps nor from their slot numbers (which would stretch the time axis by 2 %); on the
    rig's own period each row keeps its own sample."""
    k = np.arange(800)
    true_t = k * 0.01633
    stamps = np.round(true_t * 1e3) * 1e-3
    theta = np.sin(2.0 * true_t)
    rec = Recording(t=stamps, duty=np.full(k.size, 0.4), channels={"theta": theta}, source="ms.csv")
    own = uniform_recording(rec)
    assert own.meta["resampling"]["regular_instants"] and own.dt == pytest.approx(0.01633, rel=1e-4)
    assert np.array_equal(own.channels["theta"], theta)
    imposed = uniform_recording(rec, dt=0.016)
    assert imposed.dt == pytest.approx(0.016) and not imposed.meta["resampling"]["regular_instants"]
    got = imposed.channels["theta"]
    want = np.sin(2.0 * (imposed.t + true_t[0]))
    assert np.max(np.abs(got - want)) < 3e-4  # linear interpolation of a 2 rad/s sine at 16 ms
    assert imposed.t[-1] == pytest.approx(true_t[-1], abs=0.016)


def test_stamps_that_do_not_scatter_about_regular_instants_are_the_sample_instants() -> None:
    """Stamps scattered about regular instants are moved to them (:func:`regular_sampling`), with
    the period of the straight line through them, not the median interval; rows sharing a slot and
    a logger restarting at another phase after a pause keep their stamps (as at cychitivav's free
    decay); millisecond stamps of a 16.33 ms period scatter about it like any jitter."""
    rng = np.random.default_rng(0)
    T = 0.01
    k = np.arange(2000)
    err = rng.normal(0.0, 0.04 * T, k.size)
    jittered = k * T + err - err[0]
    reg = regular_sampling(jittered, grid_step(jittered))
    assert reg is not None and np.array_equal(reg.slot, k)
    assert reg.period == pytest.approx(T, rel=2e-5) and abs(grid_step(jittered) / T - 1) > 1e-4
    assert np.max(np.abs(reg.instants - (k * T - err[0]))) < 0.005 * T
    # over 2000 rows, the median interval would put the last rows this far off their slots:
    assert abs(grid_step(jittered) - T) * k[-1] > 0.2 * T
    assert regular_sampling(np.array([0.0, 0.01, 0.0125, 0.03, 0.04, 0.05]), T) is None  # a shared slot
    assert regular_sampling(k * T, T) is None  # on the grid already
    paused = np.concatenate([jittered[:1000], jittered[1000:] + 25.4 * T])  # back 0.4 T off the old phase
    assert regular_sampling(paused, grid_step(paused)) is None
    ms = np.round(k * 16.33) * 1e-3
    assert grid_step(ms) == pytest.approx(0.016)
    reg = regular_sampling(ms, grid_step(ms))
    assert reg is not None and reg.period == pytest.approx(0.01633, rel=1e-5)
    assert np.array_equal(reg.slot, k)


# ------------------------------------------------------------------ no actuator command logged


def _drop_column(src: Path, dest: Path, col: int) -> Path:
    lines = src.read_text(encoding="utf-8").splitlines()
    return _write(dest, "".join(",".join(f for i, f in enumerate(ln.split(",")) if i != col) + "\n"
                                for ln in lines))


@real_data
@pytest.mark.real_data
@pytest.mark.parametrize("name", ["closedloop_IMC_reference_steps.csv", "closedloop_STR_load_change.csv"])
def test_reference_only_log_is_refused(tmp_path: Path, name: str) -> None:
    """The closed-loop logs without their command column: θ follows reference steps, which no constant
    input does; the reference is named as what it is."""
    log = _drop_column(ETCHE / name, tmp_path / name, 1)
    spec = CsvSpec(time_col=0, angle_col="theta", reference_col="theta_ref", input_constant=0.0,
                   input_kind="pwm")
    with pytest.raises(CsvImportError) as err:
        import_csv(log, spec)
    text = str(err.value)
    assert text.startswith(f"{log}: a constant input (input_constant = 0 counts (pwm): duty 0) cannot "
                           "explain")
    assert "The reference column 'theta_ref [rad]' is not an input" in text
    assert "Log the actuator command" in text and "\n" not in text
    rec = import_csv(ETCHE / name, "etchepareborda_closedloop")
    assert check_constant_input(rec.t, rec.channels["theta"]).excess > 6.0


@real_data
@pytest.mark.real_data
@pytest.mark.parametrize("name", ["openloop_random_binary_80_120.csv", "openloop_steps_0_100_180.csv",
                                  "openloop_gaussian_pwm.csv"])
def test_driven_open_loop_log_without_its_command_is_refused(tmp_path: Path, name: str) -> None:
    log = _drop_column(ETCHE / name, tmp_path / name, 1)
    with pytest.raises(CsvImportError, match=r"a constant input \(input_constant = 0 \(duty\): duty 0\) "
                                             r"cannot explain this log: "):
        import_csv(log, CsvSpec(time_col=0, angle_col=1, input_constant=0.0))


FREE = [  # (file, spec): free decays and steps from rest in shared/data/real
    ("cychitivav__aeropendulum/data_pendulum_with_header.csv",
     CsvSpec(time_col=0, angle_col=1, angle_unit="deg", input_constant=0.0)),  # held, released, decays
    ("matheusbucater__aeropendulo/pendulum.csv",
     CsvSpec(time_col="Time", time_unit="ms", angle_col="Theta", angle_unit="deg", input_constant=0.0,
             delimiter=";")),  # free fall from 95 deg
    ("matheusbucater__aeropendulo/aeropendulum_step.csv", "matheusbucater_step"),  # step from rest
    ("dondi01__quanser_aero2_project/SATURATION_ANGLE.csv",
     CsvSpec(time_col=0, angle_col="pitch", input_constant=0.0)),  # falls from 0 onto the stop
    ("finnferdinand__orbital-stabilization-quanser-aero/pitch_coefficients/pitch_coefficients.csv",
     CsvSpec(time_col=0, angle_col=2, input_constant=0.0)),  # a kick, then 25 s of free swing
]


@real_data
@pytest.mark.real_data
@pytest.mark.parametrize(("name", "spec"), FREE, ids=[f[0].split("/")[-1] for f in FREE])
def test_free_decay_or_step_is_accepted_with_a_warning(name: str, spec: CsvSpec | str) -> None:
    with pytest.warns(ConstantInputWarning, match=r"no actuator column: the duty cycle is taken as constant "
                                                  r"over the whole log .*free decay or a step from rest"):
        rec = import_csv(REAL / name, spec)
    info = rec.meta["constant_input"]
    assert info["moves"] and info["excess"] < 0.6  # half the margin at most (docs/csv_import.md)


def _pendulum(duty: callable, t_end: float = 20.0, theta0: float = 0.0, hold: float = 0.0,
              seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """θ at 100 Hz of θ̈ = −29.8 sin θ − 0.8 θ̇ + 40 τ(t) (ω_n ≈ 5.46 rad/s, the thesis rig's step),
    held at θ0 until ``hold`` s, with 2 mrad white noise."""
    t = np.arange(0.0, t_end, 0.01)

    def rhs(tt: float, x: np.ndarray) -> list[float]:
        if tt < hold:
            return [0.0, 0.0]
        return [x[1], -29.8 * math.sin(x[0]) - 0.8 * x[1] + 40.0 * duty(tt)]

    sol = solve_ivp(rhs, (0.0, t_end), [theta0, 0.0], t_eval=t, max_step=0.005, rtol=1e-8, atol=1e-10)
    return t, sol.y[0] + np.random.default_rng(seed).normal(0.0, 0.002, t.size)


@pytest.mark.parametrize(("case", "driven"), [
    ("free decay from 0.8 rad", False),
    ("held 3 s at 0.8 rad, then released", False),
    ("step from rest at t = 0", False),
    ("at rest, noise only", False),
    ("duty stepped at t = 10 s", True),
    ("sinusoidal duty about the equilibrium", True),
    ("duty stepped every 4 s (a staircase)", True),
])
def test_constant_input_rule_on_a_simulated_pendulum(case: str, driven: bool) -> None:
    runs = {
        "free decay from 0.8 rad": lambda: _pendulum(lambda tt: 0.0, theta0=0.8),
        "held 3 s at 0.8 rad, then released": lambda: _pendulum(lambda tt: 0.0, theta0=0.8, hold=3.0),
        "step from rest at t = 0": lambda: _pendulum(lambda tt: 0.3),
        "at rest, noise only": lambda: _pendulum(lambda tt: 0.0),
        "duty stepped at t = 10 s": lambda: _pendulum(lambda tt: 0.3 if tt < 10 else 0.4),
        "sinusoidal duty about the equilibrium": lambda: _pendulum(lambda tt: 0.3 + 0.05 * math.sin(5.0 * tt),
                                                                   theta0=math.asin(12.0 / 29.8)),
        "duty stepped every 4 s (a staircase)": lambda: _pendulum(lambda tt: 0.2 + 0.05 * (tt // 4),
                                                                  t_end=24.0),
    }
    t, theta = runs[case]()
    check = check_constant_input(t, theta)
    assert check.driven is driven, (case, check.excess, check.reason)
    assert check.moves is (case != "at rest, noise only")
    assert (check.excess > 1.5) if driven else (check.excess < 0.5), check.excess


# ------------------------------------------------------------------ shipped presets unchanged


#: sha256 of t, duty and the channels (sorted by name) of every shipped preset on its real files, taken
#: before the input map and the extra channels were added (issue 36 item 2): the presets still import
#: bit-identically (the closed-loop logs moved to their own preset, etchepareborda_closedloop).
SHIPPED = {
    "aeroshield_ident2:Identification_Data2.csv":
        "1220ac83636a416f139fb6c2c9b6a9c1b4346304d451385a23a254bc86d06430",
    "aeroshield_ident:Identification_Data.csv":
        "e655da7ad67d471799f62c36e7b329cc9359b32e75a26016ff8b73ea7f63db06",
    "dondi01_aero2:NO_WEIGHTS_4V.csv.gz": "aa26c7c5fa2bcedbda96e180111590e2bbe93a384894bef9d676c92528fc7015",
    "dondi01_aero2:SATURATION_ANGLE.csv": "91c943b504e6ff2e7d503fefa955c82511ec4155fab475e69f02986635f538e7",
    "etchepareborda_closedloop:closedloop_IMC_reference_steps.csv":
        "b19da6e2c3686e03e1f9126011adccdd9f0179b904bfc60ec1d1231987f5117f",
    "etchepareborda_closedloop:closedloop_STR_load_change.csv":
        "b0778c761b990a175a3db0bad8d7f38b63aadec79ca2745688c18d4c126dadb8",
    "etchepareborda_openloop:openloop_gaussian_pwm.csv":
        "47a2d0a4505d3ae5cd239186818163e20c9d261d7a1d929ff08ecc8a8dabbc47",
    "etchepareborda_openloop:openloop_random_binary_80_120.csv":
        "019bd65e2315daba5d9c3d80a99a96701697c259ceb325424be5b7955147b060",
    "etchepareborda_openloop:openloop_steps_0_100_130.csv":
        "8fb2859068a5defa53f68c08bbe40ec72f334eb9cd279f530e1d3c74ffbfb145",
    "etchepareborda_openloop:openloop_steps_0_100_180.csv":
        "ae8b4ebe0d71666d20eb5e557e15ca4a3294baa067d7c40c6b3862523fc3e51c",
    "jahoyosr_escalones:sheet_datosEscalones_colsAB_pwm_steps_no_time.csv":
        "f0a12c0617c82895b0e4113ae71344d78e2445dcf60c2b22ff052258d94feb68",
    "jahoyosr_escalones:sheet_datosEscalones_colsST_pwm_steps_no_time.csv":
        "a7dfb016ad227e23bc265b4f3f5042488332b1fa5bd0a3de4aea376f83e234f0",
    "jahoyosr_hoja3:sheet_Hoja3_pwm_steps_openloop.csv":
        "7d88330d0ee3731d2e4a12785439e40efdceb5bcb0ce69ecff6884eb1197d580",
    "matheusbucater_sawtooth:aeropendulum.csv":
        "9ff95f0515563d0b61de3528b11f936be94265b79b8019b4c4c452bac8ffe88e",
    "matheusbucater_step:aeropendulum_step.csv":
        "db6f4b8ba2f2515fb5493498bd3d0f44601ad7ee5cc49cb65cd025d936229b71",
    "yangzhu_pitch_step:aero_pitch_step_16p5V_1kHz.csv.gz":
        "9ed8e130e2a5f22e6cf532df6a4d9c1e48e80f21ad91d9550e38ba36997293c9",
}


@real_data
@pytest.mark.real_data
def test_shipped_presets_import_bit_identically() -> None:
    found = {}
    for path in sorted(p for p in REAL.rglob("*") if p.is_file() and "original" not in p.parts):
        name = find_preset(path)
        if name is None:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = import_csv(path, name)
        h = hashlib.sha256()
        for arr in (rec.t, rec.duty):
            h.update(np.ascontiguousarray(arr, dtype=float).tobytes())
        for k in sorted(rec.channels):
            h.update(k.encode())
            h.update(np.ascontiguousarray(rec.channels[k]).tobytes())
        found[f"{name}:{path.name}"] = h.hexdigest()
    assert found == SHIPPED


def test_cli_input_flags_are_checked(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = _write(tmp_path / "log.csv", "t,u,a\n" + "".join(f"{0.01 * k:.2f},{100 + k},0.{k}\n"
                                                          for k in range(9)))
    cases = [
        (["--input-col", "u"], "--input-col needs --input-kind (one of duty, percent, pwm, voltage, "),
        (["--pwm-col", "u", "--input-kind", "voltage"], "--pwm-col is --input-kind pwm, not voltage"),
        (["--input-col", "u", "--input-kind", "voltage", "--pwm-full-scale", "1023"],
         "--pwm-full-scale applies to --input-kind pwm, not voltage"),
        (["--pwm-col", "u", "--input-col", "u", "--input-kind", "pwm"], "give one actuator column"),
        (["--pwm-col", "u", "--channel", "i_a=u:1:A"], "--channel i_a: a contract channel is in SI units"),
        (["--pwm-col", "u", "--channel", "x_acc=u"], "extra channel 'x_acc': its unit is needed"),
    ]
    for flags, message in cases:
        assert main([str(log), "--time-col", "t", "--angle-col", "a", *flags]) == 1, flags
        err = capsys.readouterr().err
        assert err.startswith("csv_import: error: ") and message in err and err.count("\n") == 1, err
    # the earlier flags still mean what they meant: PWM counts of a 10-bit timer
    assert main([str(log), "--time-col", "t", "--angle-col", "a", "--pwm-col", "u",
                 "--pwm-full-scale", "1023"]) == 0
    assert "duty 0.0978..0.1056" in capsys.readouterr().out  # 100/1023 .. 108/1023
    # a preset's map belongs to its kind: another kind starts from that kind's defaults
    from aeropend_ident.cli.csv_import import spec_from_args

    def spec(*flags: str) -> CsvSpec:
        return spec_from_args(build_parser().parse_args([str(log), "--preset", "dondi01_aero2", *flags]))

    assert spec("--input-col", "u").input_map().span == 24.0  # still the preset's voltage, V_max 24 V
    pwm = spec("--input-col", "u", "--input-kind", "pwm").input_map()
    assert (pwm.kind.name, pwm.offset, pwm.span) == ("pwm", 0.0, 255.0)


def test_tools_name_the_channels_they_ignore(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from aeropend_ident.cli.compare import main as compare_main

    t = np.arange(1500) * 0.01
    rec = Recording(t=t, duty=0.3 + 0.1 * (np.floor(t / 1.5) % 3), channels={"theta": 0.4 + 0.2 * np.sin(t)},
                    source="synthetic", extra={"phi": 0.1 * np.sin(t), "theta_ref": np.full(t.size, 0.4)})
    bag = write_bag(rec, tmp_path / "bag")
    assert compare_main([str(bag), "--rig", "thesis_sim", "--no-plots", "-o", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    assert ("ignored channels (not used by this tool; it uses θ, the duty cycle and the contract channels): "
            "phi [rad], theta_ref [rad] (in bag)") in out
